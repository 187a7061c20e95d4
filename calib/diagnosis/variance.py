"""Effects that add variance rather than a deterministic term: bias instability, and an imperfect return
to the starting pose when no accelerometer measures it.

bias_instability: g = K m + b + x(t), x a first-order Gauss-Markov process per axis with stationary
std sigma and time constant tau (calib.effects.BiasInstability). The still blocks' mean rates then
covary as sigma^2 exp(-|t_a - t_b| / tau) on top of the white-noise variance; b absorbs the common
level. Statistic: the score for sigma^2 at 0, standardised, maximised over a grid of tau (REML-style:
the constant is projected out under the white-noise weights).

placement_error without an accelerometer: each turn's closure gets an extra isotropic covariance
tau_p^2 I (the rotation the hand left the device in, unknown per turn). Statistic: the standardised
score for tau_p^2 at 0.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from calib.diagnosis.data import Problem
from calib.diagnosis.engine import System, Variance, Wander
from calib.diagnosis.gauss_newton import Fit
from calib.diagnosis.markov import GaussMarkovBlocks, correlate, posterior_variance
from calib.diagnosis.models import Model

TAU_GRID_S = (3.0, 10.0, 30.0, 100.0)


def _still_sd(prob: Problem, psi: np.ndarray) -> np.ndarray:
    """White-noise std of the still block mean rates in true-rate units, (R, 3, NB): k sigma / sqrt(n)."""
    return np.abs(psi[:, 0:3])[:, :, None] * prob.sigma[:, :, None] / np.sqrt(prob.block_n)[None, None, :]


def _still_residuals(prob: Problem, sys_: System, psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Block mean rates e (R, 3, NB) in deg/s and their white-noise std sd (R, 3, NB)."""
    R, NB = prob.R, prob.NB
    z = sys_.res[:, sys_.blocks["still"]].reshape(R, NB, 3)
    sd = _still_sd(prob, psi)
    return np.moveaxis(z, 2, 1) * sd, sd


def instability_score(prob: Problem, sys_: System, psi: np.ndarray, taus=TAU_GRID_S) -> np.ndarray:
    """Standardised score for the Gauss-Markov variance, maximised over tau: (R,)."""
    e, sd = _still_residuals(prob, sys_, psi)
    w = 1.0 / sd**2  # (R, 3, NB)
    # the constant is projected out (b is fitted with the turns too, so the residual's weighted mean is not 0)
    e = e - (w * e).sum(axis=2, keepdims=True) / w.sum(axis=2, keepdims=True)
    tb = prob.block.t[0]
    best = np.full(prob.R, -np.inf)
    we = w * e
    sw = w.sum(axis=2)
    blocks_first = np.moveaxis(np.stack((we, w), axis=-1), 2, 0)  # (NB, R, 3, 2)
    for tau in taus:
        # M (and M squared element-wise, the correlation at tau / 2) applied by the process's own recursions
        Mx = np.moveaxis(correlate(tb, tau, blocks_first), 0, 2)  # (R, 3, NB, 2)
        M2w = np.moveaxis(correlate(tb, tau / 2.0, w.transpose(2, 0, 1)), 0, 2)  # (R, 3, NB)
        Mwe, Mw = Mx[..., 0], Mx[..., 1]
        quad = np.einsum("rib,rib->ri", we, Mwe)
        trWM = sw  # M has a unit diagonal
        wMw = np.einsum("rib,rib->ri", w, Mw)
        trPM = trWM - wMw / sw
        # I = tr(P M P M) / 2 with P = W - W 1 1' W / (1' W 1)
        tr1 = np.einsum("rib,rib->ri", w, M2w)  # tr(W M W M) = sum w_a w_b M_ab^2
        tr2 = np.einsum("rib,rib->ri", w * Mw, Mw) / sw  # 1'W M W M W 1 / 1'W1
        tr3 = (wMw / sw) ** 2
        info = 0.5 * (tr1 - 2.0 * tr2 + tr3).sum(axis=1)
        score = 0.5 * (quad - trPM).sum(axis=1)
        best = np.maximum(best, score / np.sqrt(np.maximum(info, 1e-300)))
    return np.maximum(best, 0.0) ** 2


def instability_noncentrality(prob: Problem, psi: np.ndarray, sigma: float, tau: float) -> float:
    """How visible a Gauss-Markov bias (sigma deg/s, tau s) is in the still blocks of the first recording:
    the expected likelihood-ratio gain of modelling it, sum(mu - ln(1 + mu)) over the eigenvalues mu of
    its covariance in units of the white noise (the constant each axis' b absorbs projected out).

    With w = 1 / sd^2 and C = sigma^2 M + diag(sd^2): sum mu = sigma^2 (sum w - w'M w / sum w), and
    sum ln(1 + mu) = ln det C - ln det diag(sd^2) + ln(1'C^-1 1 / sum w) (the projection by a Schur complement)."""
    tb = prob.block.t[0]
    sd = _still_sd(prob, psi)[0]  # (3, NB)
    w = 1.0 / sd**2
    sw = w.sum(axis=1)
    Mw = correlate(tb, tau, w.T).T
    trace = sigma**2 * (sw - np.einsum("ib,ib->i", w, Mw) / sw)
    blocks = GaussMarkovBlocks(tb, sigma, tau, sd)
    ones = np.ones_like(sd)
    reml = np.log(np.einsum("ib,ib->i", ones, blocks.solve(ones)) / sw)
    logs = blocks.logdet() - 2.0 * np.log(sd).sum(axis=1) + reml
    return float(np.sum(trace - logs))


def instability_variance(prob: Problem, psi: np.ndarray, sigma: float, tau: float) -> Variance:
    """Covariance a Gauss-Markov bias adds (true-rate units): across the still blocks (its process, with the
    white-noise std of the blocks at ``psi``), and during each turn the part of the bias the stills around it
    do not pin down (a common offset per turn whose variance is the process's variance at the turn's middle
    given the still blocks), with the expected wander at every turn sample given the still block rates."""
    tb = prob.block.t[0]
    lay = prob.layout
    turn_var = None
    path = None
    if lay.J:
        blocks = GaussMarkovBlocks(tb, sigma, tau, _still_sd(prob, psi))
        tm = np.array([0.5 * (lay.t[s.start] + lay.t[s.end - 1]) for s in lay.turns])
        turn_var = np.maximum(posterior_variance(blocks, tm).mean(axis=1), 0.0)  # one variance per turn, axes averaged
        path = Wander(blocks, prob.turn.t[:, : lay.J])
    return Variance(still=(sigma, tau), turn_bias=turn_var, turn_path=path)


def _still_deviance(e: np.ndarray, sd: np.ndarray, tb: np.ndarray, sigma: float, tau: float) -> float:
    """Restricted deviance of the still block rates of one recording, e and sd (3, NB), under white noise
    plus a Gauss-Markov process (sigma, tau) at the block times tb, with each axis' constant integrated out,
    relative to white noise alone."""
    blocks = GaussMarkovBlocks(tb, sigma, tau, sd)
    rhs = np.stack((e, np.ones_like(e)), axis=2)  # (3, NB, 2)
    ci = blocks.solve(rhs)
    ee = np.einsum("ib,ib->i", e, ci[..., 0])
    e1 = np.einsum("ib,ib->i", e, ci[..., 1])
    one = ci[..., 1].sum(axis=1)
    quad = ee - e1**2 / one  # each axis' constant profiled out
    # restricted likelihood: the constant is integrated out, so a variance it absorbs costs nothing
    reml = np.log(one) - np.log(np.sum(1.0 / sd**2, axis=1))
    logdet = blocks.logdet() - 2.0 * np.log(sd).sum(axis=1)
    return float(np.sum(quad) + np.sum(logdet) + np.sum(reml))


TAU_MIN_S = 2.0  # shorter correlation times are white noise at the scale of the still blocks


def fit_instability(prob: Problem, base: Fit, model: Model, start: tuple[float, float] | None = None) -> tuple[float, float]:
    """Maximum-likelihood (sigma, tau) of the Gauss-Markov bias of one recording (restricted likelihood of the
    still block rates at the fit ``base`` of ``model``; the rate parameters barely move with the still weights).
    ``start``: an earlier estimate, searched around instead of over the whole grid of tau."""
    psi = base.psi
    rate, _ = model.rate(psi[:, None, :], prob.block, jacobian=False)  # (R, NB, 3) calibrated rate at rest
    e = np.moveaxis(rate, 2, 1)[0]
    sd = _still_sd(prob, psi)[0]
    tb = prob.block.t[0]
    scale = float(np.median(sd))

    def dev(log_s: float, tau: float) -> float:
        return _still_deviance(e, sd, tb, float(np.exp(log_s)), tau)

    best = (np.inf, scale, TAU_GRID_S[0])
    grid = TAU_GRID_S + (300.0,) + (() if start is None or start[0] <= 0 else (float(start[1]),))
    for tau in grid:
        r = minimize_scalar(lambda x, tau=tau: dev(x, tau), bounds=(np.log(scale * 0.05), np.log(scale * 200.0)),
                            method="bounded", options={"xatol": 0.05})
        if r.fun < best[0]:
            best = (float(r.fun), float(np.exp(r.x)), tau)
    _, sigma, tau = best
    r = minimize_scalar(lambda lt: dev(np.log(sigma), float(np.exp(lt))),
                        bounds=(np.log(max(TAU_MIN_S, tau / 3)), np.log(tau * 3)), method="bounded", options={"xatol": 0.05})
    tau = float(np.exp(r.x))
    r = minimize_scalar(lambda x: dev(x, tau), bounds=(np.log(sigma / 3), np.log(sigma * 3)), method="bounded",
                        options={"xatol": 0.02})
    return float(np.exp(r.x)), tau


def placement_score(prob: Problem, sys_: System) -> np.ndarray:
    """Standardised score for an extra isotropic closure covariance tau_p^2 I: (R,)."""
    R, J = prob.R, prob.J
    if J == 0:
        return np.zeros(R)
    r = sys_.closure.r.reshape(R, J, 3)
    Lc = sys_.chol  # (R, J, 3, 3), C = L L^T
    C = np.einsum("rjab,rjcb->rjac", Lc, Lc)
    Ci = np.linalg.inv(C)
    Cir = np.einsum("rjab,rjb->rja", Ci, r)
    score = 0.5 * (np.einsum("rja,rja->r", Cir, Cir) - np.einsum("rjaa->r", Ci))
    info = 0.5 * np.einsum("rjab,rjba->r", Ci, Ci)
    return np.maximum(score / np.sqrt(info), 0.0) ** 2


def fit_placement_variance(prob: Problem, deviance) -> float:
    """Maximum-likelihood tau_p (deg) of the per-turn placement rotation; ``deviance(tau_p)`` refits the model."""
    r = minimize_scalar(lambda lt: deviance(float(np.exp(lt))), bounds=(np.log(1e-4), np.log(20.0)), method="bounded",
                        options={"xatol": 0.02})
    return float(np.exp(r.x))
