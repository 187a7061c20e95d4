"""Where the hand put the device back after each turn, as its accelerometer saw it.

A full turn by hand ends near, not exactly at, the pose it began from. For each turn with a rest on either side, the
gravity directions of the two rests give the tilt of that placement (``calib.numerics.tilt``): the part of the
rotation from the pose before to the pose after that is perpendicular to gravity, with its standard deviation. The
part about gravity (the heading: a device spun flat on the table and put back a little turned) leaves gravity
unchanged, so no accelerometer can measure it.
"""

from __future__ import annotations

import numpy as np

from calib.noise.rests import still_statistics
from calib.numerics.tilt import tilt_across
from calib.quality import Placement, TurnPlacement
from calib.recording import Recording
from calib.stages.stage import Stage

HEADING_NOTE = ("the heading (a turn about the vertical, as when the device is spun flat and put back a little turned) "
                "leaves gravity unchanged: no accelerometer measures it")


def _neighbour_rests(turn: Stage, stills: list[Stage]) -> tuple[Stage | None, Stage | None]:
    before = max((s for s in stills if s.end <= turn.start), key=lambda s: s.end, default=None)
    after = min((s for s in stills if s.start >= turn.end), key=lambda s: s.start, default=None)
    return before, after


def measure_placement(rec: Recording, turns: list[Stage], stills: list[Stage], stages: list[Stage]) -> Placement:
    """Each turn's placement tilt, from the rests right before and after it (none without an accelerometer, or for a
    turn with another motion of ``stages`` between it and a rest: a re-orientation, a turn left out)."""
    if rec.accel is None:
        return {"measured_by": None, "note": "no accelerometer: the pose the device was put back in is not measured",
                "turns": []}
    mean, count, sigma = still_statistics(np.asarray(rec.accel, dtype=float)[None], np.array([[[s.start, s.end] for s in stills]]))
    means, sizes = mean[0], count[0]
    sigma_g = float(np.sqrt(np.mean(sigma[0] ** 2)))  # pooled over the rests and the three axes
    index = {id(s): i for i, s in enumerate(stills)}
    rows: list[TurnPlacement] = []
    for st in turns:
        before, after = _neighbour_rests(st, stills)
        between = before is not None and after is not None and any(
            m.kind != "still" and m.start != st.start and before.end <= m.start and m.end <= after.start for m in stages)
        if before is None or after is None or between:
            rows.append({"axis": st.axis, "start_s": st.start_s, "tilt_deg": None, "tilt_std_deg": None, "rotation_deg": None})
            continue
        i0, i1 = index[id(before)], index[id(after)]
        across = tilt_across(means[i0], means[i1], sizes[i0], sizes[i1], sigma_g)
        rows.append({"axis": st.axis, "start_s": st.start_s, "tilt_deg": float(np.linalg.norm(across.rho_deg)),
                     "tilt_std_deg": float(across.sd_deg), "rotation_deg": [float(v) for v in across.rho_deg]})
    return {"measured_by": "accelerometer", "note": HEADING_NOTE, "turns": rows}
