"""A kit's recordings calibrated together in a worker process (``calib.kit.estimator.calibrate_kit``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from calib.recording import Recording

from ..live import kit_guidance as say
from ..live.codes import EndReason
from .compute import LiveOutcome, recording_csv


@dataclass(frozen=True)
class KitOutcome:
    """Each wearable's outcome (a result, or why it has none), the kit's consistency, who departed, and the refusal of
    the whole kit when it could not be calibrated together."""

    outcomes: dict[str, LiveOutcome]
    consistency: dict[str, Any] | None = None
    departed: list[str] = field(default_factory=list)
    refusal: str | None = None


def calibrate_kit_live(recordings: list[Recording], names: list[str],
                       turns_kept: list[list[tuple[float, float]]] | None = None,
                       heading_prior_deg: float | None = None) -> KitOutcome:
    """Calibrate a kit session's recordings (one per wearable, in ``names``' order) together; ``turns_kept``: each
    wearable's turns its guidance took (start and end on its stamps, s), so that a turn the tray was asked again is no
    turn of the kit's. A wearable that departed from the kit, or did not turn with it at all, gets no result: the reason
    says what happened and what to do."""
    from calib.errors import GyrocalError, KitRefusal, Refusal
    from calib.kit.departure import DEPARTURE_DEG
    from calib.kit.estimator import calibrate_kit

    csvs = {name: recording_csv(rec) for name, rec in zip(names, recordings, strict=True)}
    try:
        kit = calibrate_kit(recordings, names, protocol="paper", turns_kept=turns_kept, heading_prior_deg=heading_prior_deg)
    except GyrocalError as exc:
        if isinstance(exc, KitRefusal) and exc.wearable is not None and exc.reference is not None:
            why = say.not_one_motion(exc.wearable, exc.reference)
        else:
            why = say.refused(str(exc))
        code = exc.code if isinstance(exc, Refusal) else "not_calibrated"
        return KitOutcome({n: LiveOutcome(None, why, code, csvs[n]) for n in names}, refusal=why)
    outcomes = {}
    turned = [m.name for m in kit.members if m.turned]
    for member in kit.members:
        if not member.turned:
            outcomes[member.name] = LiveOutcome(None, say.not_turned(member.name, turned), "not_one_motion",
                                                csvs[member.name], EndReason.DEPARTED)
        elif member.departed:
            d = member.coherence.departure if member.coherence is not None else None
            step = d.step_deg if d is not None and d.step_deg >= DEPARTURE_DEG else None
            outcomes[member.name] = LiveOutcome(None, say.came_apart(step), None, csvs[member.name], EndReason.DEPARTED)
        else:
            outcomes[member.name] = LiveOutcome(member.result, None, None, csvs[member.name])
    return KitOutcome(outcomes, kit.consistency(), kit.departed)
