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

from calib.diagnosis.data import Problem
from calib.diagnosis.engine import Priors, System, system
from calib.diagnosis.gauss_newton import Fit
from calib.diagnosis.models import Model
from calib.diagnosis.scores import profile_information, score_statistic
from calib.diagnosis.variance import instability_noncentrality, instability_score, placement_score
from calib.distributions import chi2_sf
from calib.effects import catalogue_specs
from calib.numerics.gram import gram

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
    sys_ = system(prob, union, psi, extend_priors(priors, base, union))
    F = gram(sys_.J)
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


def extend_priors(priors: Priors | None, src: Model, dst: Model) -> Priors | None:
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
    pri = extend_priors(priors, base, union)
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
    return float(chi2_sf(stat / c, nu))


# --------------------------------------------------------------------------- fits of extended models


RIDGE = 3.0  # effect parameters carry a weak prior N(0, (RIDGE x typical)^2)


