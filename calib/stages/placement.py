"""Where the hand put the device back after each turn, as its accelerometer saw it.

A full turn by hand ends near, not exactly at, the pose it began from. For each turn with a rest on either side, the
gravity directions of the two rests give the tilt of that placement (``calib.numerics.tilt``): the part of the
rotation from the pose before to the pose after that is perpendicular to gravity, with its standard deviation. The
part about gravity (the heading: a device spun flat on the table and put back a little turned) leaves gravity
unchanged, so no accelerometer can measure it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.noise.rests import INTERPOLATED_LAGS, RestReadings, sensor_rests
from calib.numerics.tilt import tilt_across
from calib.quality import HeadingReport, Placement, TurnPlacement
from calib.recording import Recording
from calib.stages.stage import Stage

HEADING_NOTE = ("the heading (a turn about the vertical, as when the device is spun flat and put back a little turned) "
                "leaves gravity unchanged: no accelerometer measures it")
NO_ACCEL_NOTE = "no accelerometer: the pose the device was put back in is not measured"


@dataclass(frozen=True)
class TurnTilts:
    """Each turn's measured placement tilt; NaN rows for a turn not measured."""

    rotation_deg: np.ndarray  # (J, 3) the tilt as a rotation from the pose before to the pose after (body axes), deg
    up: np.ndarray  # (J, 3) the unit gravity direction (body axes) about which the heading is unmeasured
    sd_deg: np.ndarray  # (J,) standard deviation of each of the tilt's two components, deg
    has_accel: bool

    @property
    def measured(self) -> np.ndarray:
        """(J,) whether each turn's tilt was measured."""
        return np.isfinite(self.sd_deg)


def _neighbour_rests(turn: Stage, stills: list[Stage]) -> tuple[Stage | None, Stage | None]:
    before = max((s for s in stills if s.end <= turn.start), key=lambda s: s.end, default=None)
    after = min((s for s in stills if s.start >= turn.end), key=lambda s: s.start, default=None)
    return before, after


def measure_tilts(rec: Recording, turns: list[Stage], stills: list[Stage], stages: list[Stage],
                  accel_rests: RestReadings | None = None) -> TurnTilts:
    """Each turn's placement tilt, from the rests right before and after it (none without an accelerometer, or for a
    turn with another motion of ``stages`` between it and a rest: a re-orientation, a turn left out).
    ``accel_rests``: the accelerometer's readings over ``stills`` (``calib.noise.rests.rest_readings``), when already
    measured."""
    J = len(turns)
    rotation, up, sd = np.full((J, 3), np.nan), np.full((J, 3), np.nan), np.full(J, np.nan)
    if rec.accel is None or not stills:
        return TurnTilts(rotation, up, sd, rec.accel is not None)
    rests = accel_rests if accel_rests is not None else sensor_rests(
        np.asarray(rec.accel, dtype=float), [(s.start, s.end) for s in stills], max_lag=INTERPOLATED_LAGS)
    means, sizes = rests.means, rests.counts
    # pooled over the rests and the three axes; a rest's mean scatters as its readings' spread times their colour
    # (an accelerometer interpolated onto the gyroscope's faster rate, or filtered near it, does not give as many
    # independent readings as it has samples)
    sigma_g = float(np.sqrt(np.mean(rests.spread**2) * rests.colour))
    index = {id(s): i for i, s in enumerate(stills)}
    measured, i0, i1 = [], [], []
    for j, st in enumerate(turns):
        before, after = _neighbour_rests(st, stills)
        between = before is not None and after is not None and any(
            m.kind != "still" and m.start != st.start and before.end <= m.start and m.end <= after.start for m in stages)
        if before is None or after is None or between:
            continue
        measured.append(j)
        i0.append(index[id(before)])
        i1.append(index[id(after)])
    if measured:
        across = tilt_across(means[i0], means[i1], sizes[i0], sizes[i1], sigma_g)
        rotation[measured], up[measured], sd[measured] = across.rho_deg, across.up, across.sd_deg
    return TurnTilts(rotation, up, sd, True)


def placement_report(turns: list[Stage], tilts: TurnTilts, priors: tuple[float, float] | None = None,
                     heading: HeadingReport | None = None) -> Placement:
    """The ``quality["placement"]`` of a result: each turn's measured tilt (null where not measured), and with
    ``priors`` (tilt prior, heading prior, deg) those the calibration carried, ``heading`` where the latter came from."""
    if not tilts.has_accel:
        note = NO_ACCEL_NOTE if priors is None else (
            f"{NO_ACCEL_NOTE}: the calibration carries each turn's placement (tilt and heading) as a prior of "
            f"{max(priors):.2g} deg, so its uncertainty includes it")
        return _with_priors(Placement(measured_by=None, note=note, turns=[]), priors, heading)
    rows: list[TurnPlacement] = []
    for j, st in enumerate(turns):
        if not tilts.measured[j]:
            rows.append({"axis": st.axis, "start_s": st.start_s, "tilt_deg": None, "tilt_std_deg": None, "rotation_deg": None})
            continue
        rho = tilts.rotation_deg[j]
        rows.append({"axis": st.axis, "start_s": st.start_s, "tilt_deg": float(np.linalg.norm(rho)),
                     "tilt_std_deg": float(tilts.sd_deg[j]), "rotation_deg": [float(v) for v in rho]})
    if heading is not None:
        note = f"{HEADING_NOTE}: {heading['note']}"
    elif priors is not None:
        note = (f"{HEADING_NOTE}: the calibration carries it as a prior of {priors[1]:.2g} deg per turn, so its "
                "uncertainty includes it")
    else:
        note = HEADING_NOTE
    return _with_priors(Placement(measured_by="accelerometer", note=note, turns=rows), priors, heading)


def _with_priors(report: Placement, priors: tuple[float, float] | None, heading: HeadingReport | None = None) -> Placement:
    if priors is not None:
        report["tilt_prior_deg"] = float(priors[0])
        report["heading_prior_deg"] = float(priors[1])
    if heading is not None:
        report["heading"] = heading
    return report


def measure_placement(rec: Recording, turns: list[Stage], stills: list[Stage], stages: list[Stage]) -> Placement:
    """Each turn's placement tilt as ``quality["placement"]`` reports it (``measure_tilts``, ``placement_report``)."""
    return placement_report(turns, measure_tilts(rec, turns, stills, stages))
