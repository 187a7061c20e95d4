"""Which effects the recording shows: tests calibrated on the null bootstrap, then model selection.

1. Plan. For each catalogued effect the protocol could reveal, the Fisher information of its
   parameters with the nominal ones profiled out, in units of a typical consumer-MEMS magnitude
   (``TYPICAL``), says how visible a typical effect would be (its noncentrality). Directions a typical
   effect moves by less than one standard error are left out of the test; an effect whose largest
   noncentrality is under ``IDENTIFY_MIN`` is reported as not identifiable with this protocol, with
   the motion that would reveal it.
2. Test. Each effect's statistic (Rao's score, or a standardised variance score) is computed on the
   recording and on every bootstrap replicate (null.py); a scaled chi-square matched to the replicates'
   mean and variance gives the p-value. An effect is a candidate when p < 0.05 / (number of effects
   tested): at most a 5 % chance that a recording the nominal model explains shows any effect.
3. Select. Candidates are fitted one at a time on top of the current model; the one with the lowest
   information criterion (deviance + ln(n) per effective parameter, n the number of informative numbers
   the recording holds: 3 per turn, 3 per still, 2 per measured tilt) is accepted if the criterion and
   the leave-one-stage-out prediction error (linearised PRESS) both improve, and the others are
   re-tested against it (likelihood ratio against the same scaled chi-square). Repeat until none is left.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2 as chi2_dist

from calib.diagnosis.data import Problem
from calib.diagnosis.engine import Fit, Priors, System, covariance, gauss_newton, profile_information, score_statistic, system
from calib.diagnosis.models import Model
from calib.diagnosis.variance import fit_instability, fit_placement_variance, instability_noncentrality, instability_score, placement_score
from calib.effects import catalogue_specs

ALPHA = 0.05  # family-wise false-positive rate on recordings the nominal model explains
IDENTIFY_MIN = 9.0  # noncentrality a typical effect must reach for the protocol to reveal it
DIRECTION_MIN = 1.0  # test only directions a typical effect moves by at least one standard error

# What the catalogue says of each effect (calib.effects, one EffectSpec per effect): typical magnitudes of
# consumer MEMS gyroscopes (datasheets of MPU-6050/9250, ICM-20948, LSM6DS3, BMI160), in the unit of the
# effect's drawn magnitude; the motion or channel that reveals it; what tells it from its rivals.
_SPECS = catalogue_specs()
TYPICAL: dict[str, float] = {name: spec.typical for name, spec in _SPECS.items() if spec.typical is not None}
TYPICAL_TEXT: dict[str, str] = {name: spec.typical_text for name, spec in _SPECS.items() if spec.typical_text}
ADVICE: dict[str, str] = {name: spec.reveal for name, spec in _SPECS.items()}
DISTINGUISH: dict[str, str] = {name: spec.distinguish for name, spec in _SPECS.items() if spec.distinguish}
INSTABILITY_TAU_S: float = _SPECS["bias_instability"].typical_extra["tau_s"]

WEAK_MIN = 25.0  # below this noncentrality a typical effect is more often missed than found (at a 3-dof test's threshold)


@dataclass
class TestSpec:
    """One effect's test: its model on top of the base, the tested directions and its visibility."""

    name: str  # public catalogue name
    key: str  # model effect name (bias_drift_temp for the temperature variant), or a variance kind
    kind: str  # "score", "instability" or "placement_var"
    model: Model | None = None
    idx: np.ndarray | None = None  # parameter indices in the union model
    V: np.ndarray | None = None  # tested directions (T, k) in parameter units
    noncentrality: float = 0.0
    dof: int = 0


@dataclass
class Candidate:
    name: str
    key: str
    statistic: float
    p_value: float
    dof: float
    null: tuple[float, float]  # scaled chi-square (scale c, dof nu) of the bootstrap
    noncentrality: float


@dataclass
class Step:
    """One accepted effect: the fits before and after it, its criterion and validation."""

    name: str
    key: str
    before: Fit
    after: Fit
    model: Model
    extra: dict = field(default_factory=dict)  # variance parameters (sigma, tau) or (tau_p,)
    ic: tuple[float, float] = (0.0, 0.0)
    cv: tuple[float, float] = (0.0, 0.0)
    p_value: float = 1.0
    statistic: float = 0.0
    rivals: list = field(default_factory=list)  # Cox's tests against rival explanations (rivals.RivalTest.to_dict())


def typical_scale(key: str, P: int, prob: Problem, duration: float, temp_range: float) -> np.ndarray:
    """Typical magnitude of each of an effect's P parameters."""
    if key == "bias_drift":
        return np.full(P, TYPICAL["bias_drift"] / max(duration, 1.0))
    if key == "bias_drift_temp":
        return np.full(P, TYPICAL["bias_drift"] / max(temp_range, 1e-3))
    return np.full(P, TYPICAL[key])


def plan_tests(
    prob: Problem,
    base: Model,
    base_fit: Fit,
    priors: Priors | None,
    has_accel: bool,
    has_temp: bool,
    duration: float,
    temp_range: float,
) -> tuple[list[TestSpec], Model, dict[str, str]]:
    """The tests the recording supports, the union model for the score statistics, and the effects it cannot reveal."""
    keys = ["axis_misalignment", "bias_drift", "scale_asymmetry", "scale_nonlinearity"]
    if has_temp and temp_range > 0.05:
        keys.append("bias_drift_temp")
    keys.append("g_sensitivity")  # without an accelerometer, against the gravity of a device resting flat
    if has_accel and not prob.layout.moves.any():
        keys.append("placement_error")  # re-orientations end in a new pose by design: their ends are free already
    union = base.with_effects(*keys)
    psi = union.zeros(base_fit.psi, base)
    sys_ = system(prob, union, psi, _extend_priors(priors, base, union))
    F = np.einsum("rmp,rmq->rpq", sys_.J, sys_.J)
    base_idx = np.concatenate([np.arange(union.P)[union.slices[e]] for e in ("k", "b", *base.slices) if e not in ("k", "b")]
                              + [np.arange(6)])
    base_idx = np.unique(base_idx)
    specs: list[TestSpec] = []
    not_ident: dict[str, str] = {}
    best_nc: dict[str, float] = {}
    for key in keys:
        idx = np.arange(union.P)[union.slices[key]]
        if key == "placement_error":
            # test the tilt the accelerometer measures: two directions per turn
            tl = prob.tilts()
            V = np.zeros((idx.size, 2 * prob.J))
            for j in range(prob.J):
                V[3 * j : 3 * j + 3, 2 * j : 2 * j + 2] = tl.basis[0, j].T
            finite = np.isfinite(tl.sd[0])
            V = V[:, np.repeat(finite, 2)]
            mu = np.full(V.shape[1], TYPICAL["placement_error"])
            I = profile_information(F, base_idx, idx)[0]
            Iv = V.T @ I @ V * np.outer(mu, mu)
            w, E = np.linalg.eigh(Iv) if V.shape[1] else (np.zeros(0), np.zeros((0, 0)))
            nc = float(w.max()) if w.size else 0.0
            keep = w >= DIRECTION_MIN
            Vk = (V * mu) @ E[:, keep] if keep.any() else None
        else:
            mu = typical_scale(key, idx.size, prob, duration, temp_range)
            I = profile_information(F, base_idx, idx)[0] * np.outer(mu, mu)
            w, E = np.linalg.eigh(I)
            nc = float(w.max())
            keep = w >= DIRECTION_MIN
            Vk = mu[:, None] * E[:, keep] if keep.any() else None
        name = "bias_drift" if key == "bias_drift_temp" else key
        best_nc[name] = max(best_nc.get(name, 0.0), nc)
        if nc < IDENTIFY_MIN or Vk is None:
            continue
        specs.append(TestSpec(name, key, "score", base.with_effects(key), idx, Vk, nc, int(Vk.shape[1])))
    nc = instability_noncentrality(prob, base_fit.psi, TYPICAL["bias_instability"], INSTABILITY_TAU_S) \
        if prob.layout.NB >= 4 else 0.0
    best_nc["bias_instability"] = nc
    if nc >= IDENTIFY_MIN:
        specs.append(TestSpec("bias_instability", "bias_instability", "instability", base, dof=1, noncentrality=nc))
    for name, nc in best_nc.items():
        if not any(s.name == name for s in specs):
            not_ident[name] = f"not identifiable with this recording: {ADVICE[name]}"
        elif nc < WEAK_MIN:
            factor = float(np.sqrt(WEAK_MIN / max(nc, 1e-12)))
            not_ident[name] = (f"only weakly identifiable with this recording: an effect of typical size ({TYPICAL_TEXT[name]}) "
                               f"would be missed; only about {factor:.1f} times that or more shows. {ADVICE[name].capitalize()}")
    if not has_accel and prob.J:
        specs.append(TestSpec("placement_error", "placement_var", "placement_var", base, dof=1, noncentrality=np.inf))
    return specs, union, not_ident


def _extend_priors(priors: Priors | None, src: Model, dst: Model) -> Priors | None:
    """The same pseudo-observations with parameter indices mapped from model ``src`` to ``dst``."""
    if priors is None:
        return None
    mapping = np.zeros(src.P, dtype=np.int64)
    for name, s in src.slices.items():
        mapping[np.arange(s.start, s.stop)] = np.arange(dst.slices[name].start, dst.slices[name].stop)
    return Priors(mapping[priors.idx], priors.target, priors.sd)


def statistics(prob: Problem, union: Model, base: Model, psi_base: np.ndarray, specs: list[TestSpec],
               priors: Priors | None) -> tuple[dict[str, np.ndarray], System]:
    """Each test's statistic for the R recordings of ``prob`` at their base fits psi_base (R, base.P)."""
    psi = union.zeros(psi_base, base)
    pri = _extend_priors(priors, base, union)
    if pri is not None and prob.R != pri.target.shape[0]:
        pri = Priors(pri.idx, np.broadcast_to(pri.target[:1], (prob.R, pri.idx.size)).copy(),
                     np.broadcast_to(pri.sd[:1], (prob.R, pri.idx.size)).copy())
    sys_ = system(prob, union, psi, pri)
    base_idx = np.unique(np.concatenate([np.arange(union.P)[union.slices[e]] for e in base.slices]))
    out: dict[str, np.ndarray] = {}
    for s in specs:
        if s.kind == "score":
            assert s.idx is not None and s.V is not None  # a score test has its directions
            out[s.key] = score_statistic(sys_, base_idx, s.idx, s.V)[0]
        elif s.kind == "instability":
            out[s.key] = instability_score(prob, sys_, psi)
        elif s.kind == "placement_var":
            out[s.key] = placement_score(prob, sys_)
    return out, sys_


def null_fit(values: np.ndarray) -> tuple[float, float]:
    """Scaled chi-square c * chi2(nu) with the mean and variance of bootstrap statistics."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    mean = float(v.mean()) if v.size else 0.0
    var = float(v.var(ddof=1)) if v.size > 1 else 0.0
    if mean <= 1e-12 or var <= 1e-24:
        return max(mean, 1e-12), 1.0
    c = var / (2.0 * mean)
    nu = 2.0 * mean * mean / var
    return c, max(nu, 0.05)


def p_value(stat: float, null: tuple[float, float]) -> float:
    c, nu = null
    return float(chi2_dist.sf(stat / c, nu))


# --------------------------------------------------------------------------- fits of extended models


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


RIDGE = 3.0  # effect parameters carry a weak prior N(0, (RIDGE x typical)^2)


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
    fit = refit(prob, model, psi0, pri, variance)
    if variance:
        return _state(prob, model, fit, pri, variance, keys)
    return ModelState(model, fit, pri, variance, keys)


def _state(prob: Problem, model: Model, fit: Fit, pri: Priors | None, variance: dict, keys) -> ModelState:
    """Re-estimate the variance parameters at ``fit``, then refit the model with them."""
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
    return ModelState(model, fit, pri, variance, keys)


def _extend_priors_any(priors: Priors | None, src: Model, dst: Model) -> Priors | None:
    if priors is None:
        return None
    if priors.coef is None:
        return _extend_priors(priors, src, dst)
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
