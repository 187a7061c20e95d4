"""Score statistics: how much each candidate effect would improve the fit, tested without fitting it, and the
information left for it once the nominal parameters are profiled out."""

from __future__ import annotations

import numpy as np

from calib.diagnosis.engine import System
from calib.numerics.gram import gram


def score_statistic(
    sys_: System, base_idx: np.ndarray, test_idx: np.ndarray, V: np.ndarray | None = None, rcond: float = 1e-8
) -> tuple[np.ndarray, np.ndarray]:
    """Rao's score statistic for parameters ``test_idx`` at a fit of ``base_idx`` (the others at 0).

    ``V`` (T, k) restricts the test to the directions psi[test_idx] = V c. Equals the drop of the sum
    of squares in one Gauss-Newton step of the extended model. Returns the statistic (R,) and the
    number of directions tested (R,).
    """
    Jb = sys_.J[..., base_idx]
    Jt = sys_.J[..., test_idx]
    if V is not None:
        Jt = Jt @ V
    e = sys_.res
    # project the test columns and the residual off the base columns
    A = gram(Jb)
    d = np.sqrt(np.maximum(np.einsum("rpp->rp", A), 1e-300))
    An = A / (d[:, :, None] * d[:, None, :])
    w, V = np.linalg.eigh(An)
    keep = w > 1e-12 * w[:, -1:]
    inv_w = np.where(keep, 1.0 / np.where(keep, w, 1.0), 0.0)
    Ainv = np.einsum("rpk,rk,rqk->rpq", V, inv_w, V) / (d[:, :, None] * d[:, None, :])
    JbT = Jb.transpose(0, 2, 1)
    rhs = np.concatenate((Jt, e[..., None]), axis=2)  # (R, M, T + 1): the test columns and the residual together
    perp = rhs - Jb @ (Ainv @ (JbT @ rhs))
    Jt_perp, e_perp = perp[..., :-1], perp[..., -1]
    g = np.einsum("rmt,rm->rt", Jt_perp, e_perp)
    I = gram(Jt_perp)
    # a test direction counts only if it is informed well beyond the rounding of the base projection
    scale = np.sqrt(np.maximum(np.einsum("rmt,rmt->rt", Jt, Jt), 1e-300))
    In = I / (scale[:, :, None] * scale[:, None, :])
    w2, V2 = np.linalg.eigh(In)
    keep2 = w2 > rcond
    gn = g / scale
    proj = np.einsum("rtk,rt->rk", V2, gn)
    stat = np.einsum("rk,rk->r", np.where(keep2, proj**2 / np.where(keep2, w2, 1.0), 0.0), np.ones_like(w2))
    return stat, keep2.sum(axis=1)


def profile_information(fisher: np.ndarray, base_idx: np.ndarray, test_idx: np.ndarray) -> np.ndarray:
    """Fisher information (R, T, T) of the test parameters with the base parameters profiled out."""
    Ibb = fisher[:, base_idx][:, :, base_idx]
    Ibt = fisher[:, base_idx][:, :, test_idx]
    Itt = fisher[:, test_idx][:, :, test_idx]
    sol, _ = _pinv_solve_multi(Ibb, Ibt)
    return Itt - np.einsum("rpt,rpu->rtu", Ibt, sol)


def _pinv_solve_multi(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, None]:
    d = np.sqrt(np.maximum(np.einsum("rpp->rp", A), 1e-300))
    An = A / (d[:, :, None] * d[:, None, :])
    w, V = np.linalg.eigh(An)
    keep = w > 1e-12 * w[:, -1:]
    inv_w = np.where(keep, 1.0 / np.where(keep, w, 1.0), 0.0)
    Ainv = np.einsum("rpk,rk,rqk->rpq", V, inv_w, V) / (d[:, :, None] * d[:, None, :])
    return np.einsum("rpq,rqt->rpt", Ainv, B), None
