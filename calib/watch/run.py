"""``watch``: the verdict on each parameter of a calibration from a recording made with it in force."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calib.apply.correction import Correction
from calib.recording import Recording
from calib.watch.bias import bias_findings, warm_up
from calib.watch.evidence import Evidence, gather
from calib.watch.report import WatchReport
from calib.watch.scale import ScaleFindings, scale_findings


def watch(rec: Recording, correction: Correction, temp_cal_c: float | None = None) -> WatchReport:
    """Whether ``correction`` still holds on ``rec``: each of k_x..k_z, b_x..b_z holds, moved or cannot tell.
    ``temp_cal_c``: the temperature it was made at (default: the correction's identity's, when it says). Raises
    ProtocolError when the recording has too few rests to tell anything."""
    if temp_cal_c is None and correction.identity is not None:
        temp_cal_c = correction.identity.temperature_c
    ev = gather(rec, correction)
    tau = warm_up(ev)  # without a temperature channel: the warm-up in time, which k may follow too
    scale = scale_findings(ev, temp_cal_c, tau)
    return WatchReport.of(ev, bias_findings(with_scale_moves(ev, scale), temp_cal_c, tau), scale)


def with_scale_moves(ev: Evidence, scale: ScaleFindings) -> Evidence:
    """``ev`` with its rests' bias read with the scale factors the recording showed moved, from when they moved: at
    rest a reading is -b/k, so a changed k alone changes what the calibration in force makes of it (the bias, in true
    rate, has not moved)."""
    factor = np.ones((len(ev.pieces), 3))
    t0 = ev.rec.t[0]
    for axis, p in enumerate(scale.verdicts):
        if p.verdict != "moved" or p.change is None:
            continue
        after = np.array([r.t_mid_s - t0 >= (p.since.before_s if p.since else -np.inf) for r in ev.pieces])
        factor[after, axis] = 1.0 + p.change
    if np.all(factor == 1.0):
        return ev
    b = ev.correction.b
    pieces = [replace(r, bias_dps=f * (r.bias_dps - b) + b) for r, f in zip(ev.pieces, factor, strict=True)]
    return replace(ev, pieces=pieces)
