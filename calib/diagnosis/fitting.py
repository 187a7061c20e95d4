"""Nominal fits of one recording or of many replicates."""

from __future__ import annotations

import numpy as np

from calib.diagnosis.data import Problem
from calib.diagnosis.gauss_newton import Fit, gauss_newton
from calib.diagnosis.models import Model
from calib.errors import CalibrationError, ProtocolError
from calib.estimators.closure.fit import ClosureData, start_values


def still_means(prob: Problem) -> tuple[np.ndarray, np.ndarray]:
    """Mean reading (R, S, 3) and sample count (S,) of each still, from its blocks."""
    lay = prob.layout
    n = lay.block_n()
    out = np.zeros((prob.R, lay.S, 3))
    cnt = np.zeros(lay.S)
    for s in range(lay.S):
        sel = lay.block_still == s
        cnt[s] = n[sel].sum()
        out[:, s] = (prob.block.m[:, sel] * n[sel][None, :, None]).sum(axis=1) / cnt[s]
    return out, cnt


def nominal_start(prob: Problem) -> np.ndarray:
    """Starting values (R, 6) from the stills and the integrated turns (calib.estimators.closure.fit.start_values)."""
    mean, cnt = still_means(prob)
    data = ClosureData(prob.turn.m, prob.dt, mean, np.broadcast_to(cnt, (prob.R, cnt.size)).copy(), prob.sigma)
    theta, _, rank = start_values(data)
    if np.any(rank < 3) or not np.all(np.isfinite(theta)):
        turned = ", ".join(sorted({s.axis or "?" for s in prob.layout.turns})) or "none"
        raise ProtocolError(
            f"the turns (about {turned}) do not rotate the device about all three of its axes: turn it a full "
            "360 degrees about each of x, y and z, pausing about 3 s between turns"
        )
    return theta


def fit_nominal(prob: Problem, psi0: np.ndarray | None = None, max_iter: int = 8) -> Fit:
    """The nominal model g = K m + b fitted to R recordings."""
    if prob.J == 0:
        raise ProtocolError("no full turn was found: turn the device 360 degrees about each of its axes")
    if prob.layout.S == 0:
        raise ProtocolError("no still segment was found: let the device rest about 3 s before, between and after the turns")
    psi0 = nominal_start(prob) if psi0 is None else psi0
    fit = gauss_newton(prob, Model((), prob.J), psi0, max_iter=max_iter)
    if not np.all(np.isfinite(fit.psi)):
        raise CalibrationError("the nominal fit diverged: check that each turn is one full turn that ends where it began")
    return fit


