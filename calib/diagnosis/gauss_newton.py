"""Damped Gauss-Newton over the diagnosis' whitened residual systems, with the covariance of its solution."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib.diagnosis.data import Problem
from calib.diagnosis.engine import Priors, System, Variance, system
from calib.diagnosis.models import Model
from calib.numerics.gram import gram

# a deviance change this small is no change: no test, criterion or interval the diagnosis reports can feel it, and
# chasing it (a Gauss-Newton step that ignores a variance model's log-determinant rises by about this much near the
# optimum) cost four step halvings an iteration
DEVIANCE_TOL = 1e-3
# a step that promised less than this and made things worse is not halved but not taken: the rise is the log-determinant
# the step ignores, not an overshoot a shorter step would cure (rises of 0.002-0.02 after promises of 0.001-0.003)
HALVE_PROMISE = 10 * DEVIANCE_TOL


@dataclass
class Fit:
    psi: np.ndarray  # (R, P)
    deviance: np.ndarray  # (R,)
    fisher: np.ndarray  # (R, P, P)
    dof: np.ndarray  # (R,) residuals minus identified parameters
    system: System
    iterations: int
    converged: np.ndarray
    rank: np.ndarray = field(default_factory=lambda: np.zeros(0))


def pinv_solve(A: np.ndarray, g: np.ndarray, rcond: float = 1e-10) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-norm solutions of A x = g for stacked symmetric A (R, P, P), in scaled coordinates, and ranks."""
    d = np.sqrt(np.maximum(np.einsum("rpp->rp", A), 1e-300))
    An = A / (d[:, :, None] * d[:, None, :])
    w, V = np.linalg.eigh(An)
    keep = w > rcond * w[:, -1:]
    inv_w = np.where(keep, 1.0 / np.where(keep, w, 1.0), 0.0)
    x = np.einsum("rpk,rk,rqk,rq->rp", V, inv_w, V, g / d) / d
    return x, keep.sum(axis=1)


def covariance(fisher: np.ndarray, rcond: float = 1e-10) -> np.ndarray:
    """Pseudo-inverse of stacked Fisher matrices (R, P, P) in scaled coordinates; inf variance where not identified."""
    d = np.sqrt(np.maximum(np.einsum("rpp->rp", fisher), 1e-300))
    An = fisher / (d[:, :, None] * d[:, None, :])
    w, V = np.linalg.eigh(An)
    keep = w > rcond * w[:, -1:]
    inv_w = np.where(keep, 1.0 / np.where(keep, w, 1.0), 0.0)
    cov = np.einsum("rpk,rk,rqk->rpq", V, inv_w, V) / (d[:, :, None] * d[:, None, :])
    # a parameter with a component in the null space is not identified
    null = np.einsum("rpk,rk->rp", V**2, (~keep).astype(float))
    var = np.einsum("rpp->rp", cov)
    var = np.where(null > 1e-6, np.inf, var)
    idx = np.arange(fisher.shape[1])
    cov[:, idx, idx] = var
    return cov


def gauss_newton(
    prob: Problem,
    model: Model,
    psi0: np.ndarray,
    priors: Priors | None = None,
    variance: Variance | None = None,
    max_iter: int = 8,
    tol: float = 1e-3,
) -> Fit:
    """Gauss-Newton (weights recomputed each step) for R recordings at once, with step halving."""
    psi = np.array(psi0, dtype=float)
    R = psi.shape[0]
    sys_ = system(prob, model, psi, priors, variance)
    dev = sys_.deviance()
    conv = np.zeros(R, dtype=bool)
    it = 0
    rank = np.zeros(R, dtype=np.int64)
    for it in range(1, max_iter + 1):  # noqa: B007 - the count is returned after the loop
        A = gram(sys_.J)
        g = np.einsum("rmp,rm->rp", sys_.J, sys_.res)
        step, rank = pinv_solve(A, -g)
        std = np.sqrt(np.maximum(np.einsum("rpp->rp", covariance(A)), 0.0))
        small = np.all((np.abs(step) <= tol * np.where(np.isfinite(std), std, np.inf)) | (step == 0), axis=1)
        promised = -np.einsum("rp,rp->r", g, step)  # the deviance the linearised residuals say the step gains
        small |= promised <= DEVIANCE_TOL
        if (conv | small).all():
            conv = conv | small
            break  # nothing left that the deviance could feel: the step is not worth a pass to evaluate
        lam = np.ones(R)
        new_psi = psi + step
        new = system(prob, model, new_psi, priors, variance)
        new_dev = new.deviance()
        bound = dev + np.maximum(1e-9 * np.abs(dev), DEVIANCE_TOL)  # a deviance above this is worse
        for _ in range(4):  # halve steps that made things worse
            worse = ~(new_dev <= bound) & ~conv
            if not (worse & (promised > HALVE_PROMISE)).any():
                break
            lam[worse] *= 0.5
            new_psi = psi + lam[:, None] * step
            new = system(prob, model, new_psi, priors, variance)
            new_dev = new.deviance()
        worse = ~(new_dev <= bound) & ~conv
        if worse.any():
            # no step along this direction helps (the step ignores how a variance model's determinant moves): stay
            if worse.all():
                new_psi, new, new_dev = psi, sys_, dev
            else:
                lam[worse] = 0.0
                new_psi = psi + lam[:, None] * step
                new = system(prob, model, new_psi, priors, variance)
                new_dev = new.deviance()
        settled = (np.abs(new_dev - dev) <= DEVIANCE_TOL) | worse
        psi, sys_, dev = new_psi, new, new_dev
        conv = conv | small | settled
        if conv.all():
            break
    A = gram(sys_.J)
    _, rank = pinv_solve(A, np.zeros((R, model.P)))
    M = sys_.res.shape[1] - 3 * int(prob.layout.moves.sum())  # a re-orientation's closure rows are empty
    dof = M - rank
    return Fit(psi, dev, A, dof.astype(float), sys_, it, conv, rank)
