"""One entry point for every estimator: ``calibrate(recording, method=...)``."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from calib.errors import GyrocalError, ProtocolError
from calib.estimators.registry import DEFAULT_METHOD, estimator
from calib.io.inputs import PROTOCOLS
from calib.io.section import Section
from calib.quality import AccelerometerQuality
from calib.recording import Recording
from calib.result import CalibrationResult
from calib.stages.stage import Stage

if TYPE_CHECKING:
    from calib.stages.recognise import Recognition

def calibrate(rec: Recording, method: str = DEFAULT_METHOD, stages: list[Stage] | None = None,
              heading_prior_deg: float | None = None) -> CalibrationResult:
    """Calibrate one recording of the protocol (still, then full turns about x, y, z).

    Stages are detected from the data when not given. ``heading_prior_deg``: the repeatability of the heading the
    device is put back with after each turn (closure method; None: its default). Raises RecordingError for bad input
    and ProtocolError when a stage of the protocol is missing.
    """
    result = estimator(method)(rec, stages=stages, **method_options(method, heading_prior_deg))
    return with_rate_uncertainty(replace(result, sample_rate_hz=rec.fs, n_samples=len(rec)), rec.meta.sample_rate_rel_std)


def with_rate_uncertainty(result: CalibrationResult, rel_std: float | None) -> CalibrationResult:
    """``result`` with the uncertainty of an estimated sample rate in its scale factors': the times were placed at a
    rate known to ``rel_std`` (relative), so every angle, and with it every element of K, is off by that fraction."""
    if not rel_std:
        return result
    widen = lambda std, value: None if std is None else np.hypot(std, np.abs(value) * rel_std)  # noqa: E731
    result.quality["sample_rate_rel_std"] = float(rel_std)
    return replace(result, k_std=widen(result.k_std, result.k),
                   K_std=None if result.K is None else widen(result.K_std, result.K))


def method_options(method: str, heading_prior_deg: float | None) -> dict[str, float]:
    """The estimator's keyword options; GyrocalError saying what to change for an option it does not take or a bad value."""
    if heading_prior_deg is None:
        return {}
    if method != "closure":
        raise GyrocalError(f"a heading prior is carried by the closure method only, not by {method!r}: leave it out, "
                           "or calibrate with --method closure")
    from calib.estimators.closure.placement import check_heading_prior

    return {"heading_prior_deg": check_heading_prior(heading_prior_deg)}


def calibrate_protocol(
    rec: Recording, protocol: str = "auto", method: str = DEFAULT_METHOD, sections: tuple[Section, ...] | None = None,
    stages: list[Stage] | None = None, heading_prior_deg: float | None = None,
) -> tuple[CalibrationResult, str]:
    """Calibrate a recording of ``protocol`` and say which protocol was used.

    "paper": rests, then full turns about x, y, z (``calibrate`` with ``method``). "ferraris": the same
    estimator on Ferraris' six static poses and three turns (``method="ferraris"``: Ferraris' own equations).
    "multi-position": rests in many orientations with re-orientations between them, the accelerometer as
    reference (``calib.estimators.multi_position.estimator``). "auto": what ``calib.stages.recognise`` finds; when nothing fits, the
    paper protocol's refusal. ``sections`` (or the recording's own, ``rec.meta.sections``) replace stage
    detection; ``stages`` already found (a live session's) replace both. The result's ``quality["protocol"]`` holds
    what was found and what was used. ``heading_prior_deg`` as for ``calibrate``. This is the one calibration entry
    point of every door (the command line, an upload, a live session); it raises GyrocalError (a Refusal for a recording read and refused).
    """
    check_protocol(protocol)
    estimator(method)  # an unknown method or option is refused before any work
    method_options(method, heading_prior_deg)
    sections = sections if sections is not None else rec.meta.sections
    stages, found, used = protocol_stages(rec, protocol, sections, stages)
    from calib.stages.plateaus import flag_clipped_turns

    stages = flag_clipped_turns(rec, stages)  # plateaus the stage detector's streaming rule may not see
    try:
        result = _calibrate_as(rec, used, method, stages, sections, found, heading_prior_deg)
    except GyrocalError as exc:
        if protocol == "auto" and used == "multi-position":
            # too little in the re-orientations too: the paper protocol's refusal says what to do (a wrong rate, ...)
            result = _calibrate_as(rec, "paper", method, stages, sections, found, heading_prior_deg)
            used = "paper"
        elif not isinstance(exc, ProtocolError):
            raise
        else:
            raise pointing_to(exc, used, found) from None
    result.quality["protocol"] = {"found": found.to_dict(), "used": used, "sections": len(sections)}
    if rec.mean_temperature_c is not None:  # the sensor's temperature during the recording
        result.quality["temperature_c"] = rec.mean_temperature_c
    if rec.accel is not None and "accelerometer" not in result.quality:
        result.quality["accelerometer"] = _accelerometer(rec, stages)
    if not rec.loss_visible:
        result.warnings.append(LOSS_UNSEEN)
    return result, used


# a run of samples lost inside a turn shortens it as a smaller scale factor would: said, since nothing can check it
LOSS_UNSEEN = (
    "The recording has no sample counter and its times are an exact even grid, so samples lost between the sensor and "
    "the file would leave no trace: a run lost inside a turn shortens it and reads its scale factor high by the share "
    "lost (1 % lost, k 1 % high). Keep the wearable's sample counter (a 'seq' column) or its own time stamps in the "
    "file to have lost samples found."
)


def check_protocol(protocol: str) -> None:
    """GyrocalError naming the choices when ``protocol`` is not one of ``PROTOCOLS``."""
    if protocol not in PROTOCOLS:
        raise GyrocalError(f"unknown protocol {protocol!r}: choose one of {', '.join(PROTOCOLS)}")


def protocol_stages(
    rec: Recording, protocol: str, sections: tuple[Section, ...] | None = None, stages: list[Stage] | None = None
) -> tuple[list[Stage], Recognition, str]:
    """The stages of ``rec`` (``stages`` as given, else from ``sections`` or the recording's own, else detected),
    the protocol they hold and the protocol to take them as: the one asked for, or for "auto" the one found."""
    from calib.stages.recognise import recognise

    check_protocol(protocol)
    if stages is None:
        sections = sections if sections is not None else rec.meta.sections
        if sections:
            from calib.io.sections import stages_from_sections

            stages = stages_from_sections(rec, sections)
        else:
            from calib.stages.detector import detect_stages

            stages = detect_stages(rec)
    found = recognise(rec, list(stages))
    return list(stages), found, protocol_to_use(protocol, found, rec)


def pointing_to(exc: ProtocolError, used: str, found: Recognition, doing: str = "calibrate") -> ProtocolError:
    """The refusal of the protocol asked for, pointing to the one the recording holds when that is another
    (``doing``: what to do with it, "calibrate" or "diagnose")."""
    if found.name in (used, "unrecognised", "hand-held") or (used == "paper" and found.name == "ferraris"):
        return exc
    better = "multi-position" if found.name == "mixed" else found.name
    return ProtocolError(f"{str(exc).rstrip('.')}. The recording holds {found.summary}: {doing} it with --protocol {better} (or auto)",
                         code=exc.code, stages=exc.stages)


def _calibrate_as(
    rec: Recording, used: str, method: str, stages: list[Stage], sections: tuple[Section, ...], found: Recognition,
    heading_prior_deg: float | None = None,
) -> CalibrationResult:
    if used == "multi-position":
        if sections and any(b.start != a.end or a.kind == b.kind == "still" for a, b in zip(sections, sections[1:], strict=False)):
            raise ProtocolError("the labelled sections do not hold every motion between two rests (two rests follow each "
                                "other, or samples between sections are missing), so the re-orientations cannot be "
                                "followed; calibrate without the sections, or choose --protocol paper or ferraris",
                                code="sections_incomplete")
        from calib.estimators.multi_position.estimator import calibrate_multi_position

        return with_rate_uncertainty(calibrate_multi_position(rec, stages), rec.meta.sample_rate_rel_std)
    if used == "ferraris" and len(found.poses) < 6:
        from calib.estimators.ferraris import ferraris_stages

        ferraris_stages(rec, stages)  # raises, naming the poses and turns that are missing
    return calibrate(rec, method=method, stages=stages, heading_prior_deg=heading_prior_deg)


def _accelerometer(rec: Recording, stages: list[Stage]) -> AccelerometerQuality | None:
    """The accelerometer's calibration from the recording's rests, reported beside the gyroscope's; None when the
    rests cannot give one."""
    from calib.estimators.accel import calibrate_accelerometer

    try:
        return calibrate_accelerometer(rec, [s for s in stages if s.kind == "still"]).to_dict()
    except GyrocalError:
        return None


def protocol_to_use(protocol: str, found: Recognition, rec: Recording) -> str:
    """The protocol to calibrate with: the one asked for, or for "auto" the one found."""
    if protocol != "auto":
        return protocol
    if found.name in ("ferraris", "paper"):
        return found.name
    if found.name in ("multi-position", "mixed") and rec.accel is not None:
        return "multi-position"
    if found.quietest_second is not None:  # hand-held
        from calib.stages.hints import quiet_text

        raise ProtocolError(
            f"the device was held in the hand throughout, there is no rest anywhere in the recording: "
            f"{quiet_text(found.quietest_second)}. Without a rest the gyro's offset cannot be told apart from its scale "
            "factors, and where each full turn begins and ends (the pose the hand comes back to) is not known, so gyrocal "
            "does not calibrate it. Put the device down, still, for about 3 s before, between and after the turns",
            code="no_rest")
    return "paper"  # nothing recognised: the paper protocol's own refusal says what is missing
