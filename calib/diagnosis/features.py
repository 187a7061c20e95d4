"""Residual features of a nominal fit: what the simulator must reproduce for the recording to look typical.

Every feature is computed the same way on the recording and on each simulated replicate of it
(calib.diagnosis.null), from the nominal model's fit:

- ``still_rate``  per still and axis: the calibrated mean rate at rest (deg/s), 0 under the model;
- ``whiteness``   per still: chi-square per degree of freedom of its block means about the still's
                  mean (about 1 for white noise, larger when the zero-rate output wanders);
- ``closure``     per turn and axis: the closing rotation (deg), 0 when the turn came back;
- ``tilt``        per turn (with an accelerometer): the tilt between the poses before and after (deg);
- ``gravity``     per re-orientation: the angle between the gravity the calibrated gyro carries from the
                  pose after to the pose before and the accelerometer's there (deg), 0 under the model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.diagnosis.data import Layout, Problem
from calib.diagnosis.engine import System
from calib.stages.stage import AXES

SIGNED = "signed"
UPPER = "upper"


@dataclass
class Features:
    """Feature values (R, F) with a name, a location and a kind (signed or upper) per feature."""

    values: np.ndarray
    names: list[str]
    where: list[str]
    kinds: list[str]
    groups: list[str]  # still_rate, whiteness, closure, tilt


def _still_label(layout: Layout, s: int) -> str:
    st = layout.stills[s]
    return f"still {s + 1} ({st.start_s:.1f}-{st.end_s:.1f} s)"


def _turn_label(layout: Layout, j: int) -> str:
    return window_label(layout, j, f" ({layout.turns[j].start_s:.1f}-{layout.turns[j].end_s:.1f} s)")


def window_label(layout: Layout, j: int, when: str | None = None) -> str:
    """"turn about x at 12.3 s" or "re-orientation 4 at 12.3 s" (``when`` replaces " at 12.3 s")."""
    st = layout.turns[j]
    when = f" at {st.start_s:.1f} s" if when is None else when
    if layout.moves[j]:
        return f"re-orientation {int(layout.moves[: j + 1].sum())}{when}"
    return f"turn about {st.axis}{when}"


def compute_features(prob: Problem, sys_: System, psi: np.ndarray) -> Features:
    """Features of R recordings from their nominal fit (system at the solution psi (R, 6))."""
    lay = prob.layout
    R, NB, S, J = prob.R, lay.NB, lay.S, lay.J
    sl = sys_.blocks["still"]
    z = sys_.res[:, sl].reshape(R, NB, 3)  # whitened block rates
    k = psi[:, 0:3]
    sd = np.abs(k)[:, None, :] * prob.sigma[:, None, :] / np.sqrt(prob.block_n)[None, :, None]
    e = z * sd  # block mean rates, deg/s
    cols, names, where, kinds, groups = [], [], [], [], []
    owner = lay.block_still
    n = lay.block_n()
    for s in range(S):
        sel = owner == s
        w = n[sel]
        mean = (e[:, sel] * w[None, :, None]).sum(axis=1) / w.sum()
        for i, a in enumerate(AXES):
            cols.append(mean[:, i])
            names.append(f"still_rate_{s}_{a}")
            where.append(f"{_still_label(lay, s)}, axis {a}")
            kinds.append(SIGNED)
            groups.append("still_rate")
    for s in range(S):
        sel = owner == s
        nb = int(sel.sum())
        if nb < 2:
            continue
        w = n[sel]
        mean = (e[:, sel] * w[None, :, None]).sum(axis=1) / w.sum()
        dev = (e[:, sel] - mean[:, None, :]) / sd[:, sel]
        chi = (dev**2).sum(axis=(1, 2)) / (3.0 * (nb - 1))
        cols.append(chi)
        names.append(f"whiteness_{s}")
        where.append(_still_label(lay, s))
        kinds.append(UPPER)
        groups.append("whiteness")
    moves = lay.moves
    if J:
        r = sys_.closure.r.reshape(R, J, 3)
        for j in map(int, np.flatnonzero(~moves)):
            for i, a in enumerate(AXES):
                cols.append(r[:, j, i])
                names.append(f"closure_{j}_{a}")
                where.append(f"{_turn_label(lay, j)}, {a} component")
                kinds.append(SIGNED)
                groups.append("closure")
    if prob.tilt is not None and prob.tilt_sd is not None and moves.any():
        tl = prob.tilts()
        r = sys_.closure.r.reshape(R, J, 3)
        miss = tl.tilt - np.einsum("rjci,rji->rjc", tl.basis, r)  # deg, exact for the re-orientations
        for j in map(int, np.flatnonzero(moves)):
            cols.append(np.linalg.norm(miss[:, j], axis=1))
            names.append(f"gravity_{j}")
            where.append(f"{_turn_label(lay, j)}: gravity carried by the gyro vs the accelerometer")
            kinds.append(UPPER)
            groups.append("gravity")
    if prob.tilt is not None and prob.tilt_sd is not None and J:
        for j in map(int, np.flatnonzero(~moves)):
            if not np.all(np.isfinite(prob.tilt_sd[:, j])):
                continue
            cols.append(np.linalg.norm(prob.tilt[:, j], axis=1))
            names.append(f"tilt_{j}")
            where.append(f"{_turn_label(lay, j)}: pose after vs before (accelerometer)")
            kinds.append(UPPER)
            groups.append("tilt")
    values = np.stack(cols, axis=1) if cols else np.zeros((R, 0))
    return Features(values, names, where, kinds, groups)
