"""Fits of models extended by candidate effects: their priors, each model's state, adding one effect to a state, and
the criteria that compare states."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib.diagnosis.data import Problem
from calib.diagnosis.engine import Priors
from calib.diagnosis.gauss_newton import Fit, covariance, gauss_newton
from calib.diagnosis.models import Model
from calib.diagnosis.select import RIDGE, TYPICAL, extend_priors, typical_scale
from calib.diagnosis.variance import fit_instability, fit_placement_variance


def informative_count(prob: Problem, has_tilt: bool) -> int:
    n = 3 * (prob.J - int(prob.layout.moves.sum())) + 3 * prob.layout.S
    if has_tilt and prob.tilt_sd is not None:
        n += 2 * int(np.isfinite(prob.tilt_sd[0]).sum())
    return max(n, 2)


def placement_priors(prob: Problem, model: Model, psi: np.ndarray) -> Priors:
    """Heading prior of the placement rotations: rho . up ~ N(0, tau_h^2), tau_h from the measured tilts."""
    J = prob.J
    s = model.slices["placement_error"].start
    tl = prob.tilts()
    tilt = tl.tilt[0]
    finite = np.isfinite(tl.sd[0])
    rms = float(np.sqrt(np.mean(tilt[finite] ** 2))) if finite.any() else TYPICAL["placement_error"]
    floor = 3.0 * float(np.median(tl.sd[0][finite])) if finite.any() else 0.01
    tau_h = max(rms, floor)
    coef = np.zeros((1, J, model.P))
    for j in range(J):
        coef[0, j, s + 3 * j : s + 3 * j + 3] = tl.up[0, j]
    return Priors(np.zeros(J, dtype=np.int64), np.zeros((1, J)), np.full((1, J), tau_h), coef)


def ridge_priors(prob: Problem, model: Model, key: str) -> Priors:
    """Weak prior on an effect's parameters: directions the recording does not inform stay plausible."""
    idx = np.arange(model.P)[model.slices[key]]
    duration = float(prob.layout.t[-1]) if prob.layout.n else 1.0
    temp_range = float(np.ptp(prob.block.temp[0])) if prob.block.temp is not None else 1.0
    mu = typical_scale(key, idx.size, prob, duration, temp_range)
    return Priors(idx, np.zeros((1, idx.size)), (RIDGE * mu)[None, :])


def merge_priors(a: Priors | None, b: Priors | None, P: int) -> Priors | None:
    """Two sets of pseudo-observations as one (rows with coefficients)."""
    parts = [p for p in (a, b) if p is not None]
    if not parts:
        return None
    coefs, targets, sds = [], [], []
    for p in parts:
        if p.coef is not None:
            c = np.zeros(p.coef.shape[:2] + (P,))
            c[..., : p.coef.shape[2]] = p.coef
        else:
            c = np.zeros((p.target.shape[0], p.idx.size, P))
            c[:, np.arange(p.idx.size), p.idx] = 1.0
        coefs.append(c)
        targets.append(p.target)
        sds.append(p.sd)
    return Priors(np.zeros(sum(t.shape[1] for t in targets), dtype=np.int64), np.concatenate(targets, axis=1),
                  np.concatenate(sds, axis=1), np.concatenate(coefs, axis=1))


@dataclass
class ModelState:
    """A fitted model of the recording: effects with parameters, variance parts and priors."""

    model: Model
    fit: Fit
    priors: Priors | None
    variance: dict = field(default_factory=dict)  # "bias_instability": (sigma, tau), "placement_var": tau_p
    keys: tuple[str, ...] = ()


def fit_state(prob: Problem, state: ModelState, key: str, base_priors: Priors | None) -> ModelState:
    """``state`` extended by the effect ``key`` and refitted; variance parameters already in the model are
    re-estimated with it (an effect that explains part of the misfit leaves less for them)."""
    keys = state.keys + (key,)
    model = state.model
    variance = dict(state.variance)
    pri = state.priors
    if key in ("bias_instability", "placement_var"):
        variance[key] = (0.0, 1.0) if key == "bias_instability" else 0.0
        return _state(prob, model, state.fit, pri, variance, keys)
    model = model.with_effects(key)
    psi0 = model.zeros(state.fit.psi, state.model)
    pri = _extend_priors_any(state.priors, state.model, model)
    if key != "placement_error":
        pri = merge_priors(pri, ridge_priors(prob, model, key), model.P)
    if key == "placement_error":
        # start the placement rotations at the measured tilts
        s = model.slices["placement_error"].start
        tl = prob.tilts()
        for j in range(prob.J):
            if np.isfinite(tl.sd[0, j]):
                psi0[0, s + 3 * j : s + 3 * j + 3] = tl.basis[0, j].T @ tl.tilt[0, j]
        pri = merge_priors(pri, placement_priors(prob, model, psi0), model.P)
    return _state(prob, model, refit(prob, model, psi0, pri, variance), pri, variance, keys)


def refit_state(prob: Problem, state: ModelState) -> ModelState:
    """``state``'s model fitted to ``prob`` (another recording of the same layout) from ``state``'s parameters, its
    variance parts re-estimated."""
    fit = refit(prob, state.model, state.fit.psi, state.priors, state.variance)
    return _state(prob, state.model, fit, state.priors, state.variance, state.keys)


def _state(prob: Problem, model: Model, fit: Fit, pri: Priors | None, variance: dict, keys) -> ModelState:
    """Re-estimate the variance parameters at ``fit``, then refit the model with them (nothing to do without any)."""
    if not variance:
        return ModelState(model, fit, pri, {}, keys)
    old_var, old_fit = dict(variance), fit
    variance = dict(variance)
    if "bias_instability" in variance:
        variance["bias_instability"] = fit_instability(prob, fit, model, variance["bias_instability"])
    if "placement_var" in variance:
        others = {k: v for k, v in variance.items() if k != "placement_var"}

        def deviance(tp: float) -> float:
            var = dict(others, placement_var=tp)
            return float(refit(prob, model, fit.psi, pri, var, max_iter=1).deviance[0])

        variance["placement_var"] = fit_placement_variance(prob, deviance)
    fit = refit(prob, model, fit.psi, pri, variance)
    if old_var.get("bias_instability", (0.0, 1.0))[0] > 0 and float(old_fit.deviance[0]) < float(fit.deviance[0]):
        # the wander is estimated from the still blocks alone; where the turns or re-orientations fit worse with the new
        # estimate than with the one it started from (an effect took over what the wander explained at the rests), the
        # earlier one is kept
        return ModelState(model, old_fit, pri, old_var, keys)
    return ModelState(model, fit, pri, variance, keys)


def _extend_priors_any(priors: Priors | None, src: Model, dst: Model) -> Priors | None:
    if priors is None:
        return None
    if priors.coef is None:
        return extend_priors(priors, src, dst)
    mapping = np.zeros(src.P, dtype=np.int64)
    for name, s in src.slices.items():
        mapping[np.arange(s.start, s.stop)] = np.arange(dst.slices[name].start, dst.slices[name].stop)
    coef = np.zeros(priors.coef.shape[:2] + (dst.P,))
    coef[..., mapping] = priors.coef
    return Priors(priors.idx, priors.target, priors.sd, coef)


def variance_of(prob: Problem, psi: np.ndarray, variance: dict):
    from calib.diagnosis.engine import Variance
    from calib.diagnosis.variance import instability_variance

    if not variance:
        return None
    v = Variance()
    if "bias_instability" in variance:
        sigma, tau = variance["bias_instability"]
        v = instability_variance(prob, psi, sigma, tau)
    if "placement_var" in variance:
        tp = variance["placement_var"]
        v.closure = np.broadcast_to(np.eye(3) * tp**2, (prob.R, prob.J, 3, 3)).copy()
    return v


def gm_of(state: ModelState) -> tuple[np.ndarray, float] | None:
    """The state's Gauss-Markov bias as the simulator takes it: (sigma per axis (3,), tau), or None."""
    if "bias_instability" in state.variance:
        sigma, tau = state.variance["bias_instability"]
        return np.full(3, sigma), tau
    return None


def try_fit(prob: Problem, cur: ModelState, key: str, base_priors: Priors | None) -> ModelState | None:
    """``cur`` extended by ``key`` and refitted, or None when that fit fails or diverges."""
    try:
        st = fit_state(prob, cur, key, base_priors)
    except (np.linalg.LinAlgError, ValueError, FloatingPointError):
        return None
    return st if np.all(np.isfinite(st.fit.psi)) and np.isfinite(st.fit.deviance[0]) else None


def criterion(state: ModelState, pen: float) -> float:
    """Information criterion of a fitted state: deviance + pen per effective parameter (variance parts included)."""
    extra = 2.0 * ("bias_instability" in state.variance) + 1.0 * ("placement_var" in state.variance)
    return float(state.fit.deviance[0]) + pen * (effective_params(state.fit) + extra)


def refit(prob: Problem, model: Model, psi0: np.ndarray, priors: Priors | None, variance: dict, max_iter: int = 10) -> Fit:
    return gauss_newton(prob, model, psi0, priors=priors, variance=variance_of(prob, psi0, variance), max_iter=max_iter)


def effective_params(fit: Fit) -> float:
    """Trace of the hat matrix: the number of parameters the data (not the priors) determine."""
    J = fit.system.J[0]
    rows = fit.system.blocks.get("prior")
    cov = covariance(fit.fisher)[0]
    cov = np.where(np.isfinite(cov), cov, 0.0)
    H = np.einsum("mp,pq,mq->m", J, cov, J)
    if rows is not None:
        H[rows] = 0.0
    return float(H.sum())


def press(fit: Fit, prob: Problem) -> float:
    """Leave-one-stage-out prediction error (linearised): each turn, each still, each tilt pair held out in turn."""
    sys_ = fit.system
    J = sys_.J[0]
    e = sys_.res[0]
    cov = covariance(fit.fisher)[0]
    cov = np.where(np.isfinite(cov), cov, 0.0)
    groups: list[np.ndarray] = []
    if "closure" in sys_.blocks:
        s = sys_.blocks["closure"].start
        groups += [np.arange(s + 3 * j, s + 3 * j + 3) for j in np.flatnonzero(~prob.layout.moves)]
    s0 = sys_.blocks["still"].start
    owner = prob.layout.block_still
    for st in range(prob.layout.S):
        blocks = np.flatnonzero(owner == st)
        groups.append((s0 + 3 * blocks[:, None] + np.arange(3)).ravel())
    if "tilt" in sys_.blocks:
        s = sys_.blocks["tilt"].start
        groups += [np.arange(s + 2 * j, s + 2 * j + 2) for j in range(prob.J)]
    total = 0.0
    for g in groups:
        Jg = J[g]
        Hgg = Jg @ cov @ Jg.T
        w, V = np.linalg.eigh(np.eye(g.size) - Hgg)
        keep = w > 1e-3  # components another stage cannot predict are left out
        proj = V[:, keep].T @ e[g]
        # held-out predictive deviance: the prediction error has covariance (I - H_gg)^-1 (whitened)
        total += float(np.sum(proj**2 / w[keep] - np.log(w[keep])))
    return total + float(sys_.logdet[0])
