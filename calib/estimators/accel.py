"""Accelerometer calibration from rests: the 9-parameter model fitted to |a| = 1 g over every rest.

Model (Tedaldi, Pretto, Menegatti, ICRA 2014 — imu_tk's; readings r and calibrated a in g):

    a = T S (r - o),   S = diag(s),   T = [[1, -a_yz, a_zy], [0, 1, -a_zx], [0, 0, 1]]

with scale factors s (dimensionless), offsets o (g, in reading units) and the three small
non-orthogonality angles (rad) of T. At rest the calibrated specific force has magnitude 1 g, so each
rest gives one equation |a_i| = 1; the fit is a nonlinear least squares over the rests' mean readings.
Nine parameters need rests in enough different orientations: with too few (or too alike) the
misalignment, then the scale factors are held at their nominal values (0, 1) and the result says so.
Uncertainties are the least-squares covariance scaled by the residual variance (the rests' spread
about 1 g includes any hand tremor, so the noise level is measured, not assumed).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calib.errors import CalibrationError
from calib.numerics.windows import span_means
from calib.quality import AccelerometerQuality
from calib.recording import Recording
from calib.stages.stage import Stage

PARAMS = ("s_x", "s_y", "s_z", "o_x", "o_y", "o_z", "a_yz", "a_zy", "a_zx")
MIN_RESTS = {9: 12, 6: 9, 3: 4}  # rests needed for each model: at least a few more than its parameters
CONDITION_MAX = 1e6  # a worse-conditioned fit does not identify every parameter of its model
# a fit that its rests determine converges from the nominal start in a few steps (4-6 on imucal's session, 5 on
# imu_tk's 38 rests for all nine parameters); one still wandering after this many evaluations is along a direction
# they do not determine (900 of them on imucal's session, whose misalignment is not identified, were 94 % of its
# calibration's time)
MAX_EVALUATIONS = 30
MIN_REST_SAMPLES = 10
REST_TRIM_S = 0.25  # each rest's first and last quarter second left out (the hand lets go, the device settles)


class AccelCalibrationError(CalibrationError, ValueError):
    """The rests cannot calibrate the accelerometer; the message says what is missing."""

    default_code = "accelerometer_not_determined"


@dataclass(frozen=True)
class AccelCalibration:
    """A calibrated accelerometer: ``a = T S (r - o)`` (see the module docstring), with its uncertainty."""

    scale: np.ndarray  # (3,) s
    offset: np.ndarray  # (3,) o, g
    misalignment: np.ndarray  # (3,) a_yz, a_zy, a_zx, rad
    scale_std: np.ndarray | None = None
    offset_std: np.ndarray | None = None
    misalignment_std: np.ndarray | None = None
    n_rests: int = 0
    residual_rms_g: float = 0.0  # rms of |a_i| - 1 over the rests after calibration
    residuals_g: np.ndarray = field(default_factory=lambda: np.zeros(0))  # |a_i| - 1 per rest
    identified: tuple[str, ...] = PARAMS
    note: str = ""

    @classmethod
    def from_fit(cls, x: np.ndarray, std: np.ndarray, free: np.ndarray, residuals: np.ndarray, note: str) -> AccelCalibration:
        """The calibration from a fitted parameter vector ``x`` (9, in ``PARAMS`` order), the std of its ``free`` entries
        (the others held at nominal) and the rests' residuals |a_i| - 1."""
        return cls(
            scale=x[0:3].copy(), offset=x[3:6].copy(), misalignment=x[6:9].copy(),
            scale_std=std[0:3].copy() if free[0:3].any() else None, offset_std=std[3:6].copy(),
            misalignment_std=std[6:9].copy() if free[6:9].all() else None,
            n_rests=int(residuals.size), residual_rms_g=float(np.sqrt(np.mean(residuals**2))), residuals_g=residuals.copy(),
            identified=tuple(p for p, f in zip(PARAMS, free, strict=True) if f), note=note,
        )

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> AccelCalibration:
        """The calibration's model parameters from its ``to_dict`` form (a result's ``quality["accelerometer"]``)."""
        return cls(scale=np.asarray(d["scale"], float), offset=np.asarray(d["bias"], float),
                   misalignment=np.asarray(d["misalignment"], float))

    @property
    def vector(self) -> np.ndarray:
        """The parameters (9,) in ``PARAMS`` order."""
        return np.concatenate([self.scale, self.offset, self.misalignment])

    @property
    def matrix(self) -> np.ndarray:
        """T S (3, 3)."""
        return _t_matrix(self.misalignment) @ np.diag(self.scale)

    def apply(self, readings: np.ndarray) -> np.ndarray:
        """Calibrated specific force (g) of raw readings (..., 3) in g."""
        return apply_model(self.vector, np.asarray(readings, dtype=float))

    def to_dict(self) -> AccelerometerQuality:
        """JSON-ready: scale, bias (the offset o, g), misalignment (rad), uncertainty, fit quality."""

        def lst(a: np.ndarray | None) -> list[float] | None:
            return None if a is None else [float(v) for v in a]

        return {
            "model": "a = T S (r - o)",
            "scale": lst(self.scale),
            "bias": lst(self.offset),
            "misalignment": lst(self.misalignment),
            "uncertainty": {"scale": lst(self.scale_std), "bias": lst(self.offset_std), "misalignment": lst(self.misalignment_std)},
            "n_rests": self.n_rests,
            "residual_rms_mg": 1e3 * self.residual_rms_g,
            "identified": list(self.identified),
            "note": self.note,
        }


def _t_matrix(mis: np.ndarray) -> np.ndarray:
    a_yz, a_zy, a_zx = mis
    return np.array([[1.0, -a_yz, a_zy], [0.0, 1.0, -a_zx], [0.0, 0.0, 1.0]])


def apply_model(x: np.ndarray, raw: np.ndarray) -> np.ndarray:
    """T S (raw - o) for the parameters ``x`` (9, in ``PARAMS`` order) and raw readings (..., 3) in g."""
    return ((raw - x[3:6]) * x[0:3]) @ _t_matrix(x[6:9]).T


NOMINAL = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
DISTINCT_DEG = 10.0  # rests whose gravity directions lie closer than this give one equation twice, not two
SCALE_SPAN = 1.0  # an axis's scale needs rests with it pointing well up and well down (span of its gravity share)
OFFSET_SPAN = 0.5  # its offset, rests with it tilted clearly different ways


def _residuals(x: np.ndarray, free: np.ndarray, means: np.ndarray) -> np.ndarray:
    full = NOMINAL.copy()
    full[free] = x
    return np.linalg.norm(apply_model(full, means), axis=1) - 1.0


def _jacobian(x: np.ndarray, free: np.ndarray, means: np.ndarray) -> np.ndarray:
    """d(|a_i| - 1)/d(free parameters), (N, free): with d = r - o, u = S d, a = T u and g = a / |a|, the derivative
    along a parameter is g . da/dparameter, where da/ds_k = T[:, k] d_k, da/do_k = -T[:, k] s_k, and the angles move
    a_x by -u_y (a_yz) and u_z (a_zy), a_y by -u_z (a_zx)."""
    full = NOMINAL.copy()
    full[free] = x
    scale, offset, mis = full[0:3], full[3:6], full[6:9]
    t = _t_matrix(mis)
    d = means - offset
    u = d * scale
    a = u @ t.T
    g = a / np.linalg.norm(a, axis=1, keepdims=True)
    gt = g @ t  # g . T[:, k] for each k
    jac = np.column_stack([gt * d, -gt * scale, -g[:, 0] * u[:, 1], g[:, 0] * u[:, 2], -g[:, 1] * u[:, 2]])
    return jac[:, free]


def distinct_orientations(means: np.ndarray) -> int:
    """How many of the rests' gravity directions differ by ``DISTINCT_DEG`` or more: each group of rests closer than
    that to the first of it counts once (a pose rested in twice gives the fit one equation, not two)."""
    u = means / np.linalg.norm(means, axis=1, keepdims=True)
    close = u @ u.T > np.cos(np.radians(DISTINCT_DEG))
    counted = np.zeros(u.shape[0], dtype=bool)
    groups = 0
    for i in range(u.shape[0]):
        if not counted[i]:
            groups += 1
            counted |= close[i]
    return groups


def _plans(means: np.ndarray) -> list[tuple[np.ndarray, str]]:
    """The parameter sets to try, largest first, each with what it leaves out: what the rests' orientations allow.
    A plan needs more rests than parameters and at least as many distinct orientations as parameters (fewer leave
    a direction of the parameters no rest sees, along which a fit only wanders)."""
    u = means / np.linalg.norm(means, axis=1, keepdims=True)
    span = u.max(axis=0) - u.min(axis=0)
    scale_ok, offset_ok = span >= SCALE_SPAN, span >= OFFSET_SPAN
    N, distinct = means.shape[0], distinct_orientations(means)
    held = [f"{ax}'s scale (the {ax} axis never pointed well up and well down)" for ax, ok in zip("xyz", scale_ok, strict=True) if not ok]
    held += [f"{ax}'s offset (the {ax} axis hardly changed its tilt)" for ax, ok in zip("xyz", offset_ok, strict=True) if not ok]
    base = np.concatenate([scale_ok, offset_ok, np.zeros(3, dtype=bool)])
    plans = []
    if scale_ok.all() and N >= MIN_RESTS[9] and distinct >= 9:
        plans.append((np.concatenate([base[:6], np.ones(3, dtype=bool)]), held))
    why = ("" if N >= MIN_RESTS[9] else f" ({MIN_RESTS[9]} rests needed, {N} given)") or (
        "" if distinct >= 9 else f" (rests in 9 different orientations needed, {distinct} given)")
    plans.append((base, [*held, "the misalignment" + why]))
    plans.append((np.concatenate([np.zeros(3, dtype=bool), offset_ok, np.zeros(3, dtype=bool)]), [*held, "the scale factors"]))
    return [(free, "held at nominal: " + "; ".join(h) if h else "") for free, h in plans
            if free.sum() and N >= free.sum() + 1 and distinct >= free.sum()]


def fit_accelerometer(means: np.ndarray) -> AccelCalibration:
    """Calibrate from the mean readings (N, 3) in g of N rests in different orientations."""
    means = np.asarray(means, dtype=float).reshape(-1, 3)
    means = means[np.all(np.isfinite(means), axis=1) & (np.linalg.norm(means, axis=1) > 0.1)]
    N = means.shape[0]
    if N < MIN_RESTS[3]:
        raise AccelCalibrationError(
            f"the recording has {N} rests with the accelerometer; calibrating it needs at least {MIN_RESTS[3]} rests in "
            "different orientations (put the device down on each face and edge, a few seconds each)")
    from scipy.optimize import leastsq  # here, not above: importing scipy.optimize costs 0.4 s of a service's start

    tried = []
    for free, note in _plans(means):
        # MINPACK's Levenberg-Marquardt (lmder) with the analytic Jacobian, each parameter scaled by its column's norm;
        # leastsq calls it with a fraction of least_squares' wrapping, which was most of this fit's time
        x, _, info, _, ier = leastsq(_residuals, NOMINAL[free], args=(free, means), Dfun=_jacobian, full_output=True,
                                     ftol=1e-8, xtol=1e-8, gtol=1e-8, maxfev=MAX_EVALUATIONS)
        jac, fun = _jacobian(x, free, means), info["fvec"]
        sv = np.linalg.svd(jac, compute_uv=False)
        if ier not in (1, 2, 3, 4) or sv[-1] <= 0 or sv[0] / sv[-1] > CONDITION_MAX:
            tried.append(f"{int(free.sum())} parameters are not separated by the rests' orientations")
            continue
        s2 = float(fun @ fun) / max(N - int(free.sum()), 1)
        std_free = np.sqrt(np.diag(np.linalg.inv(jac.T @ jac) * s2))
        full, std = NOMINAL.copy(), np.full(9, np.nan)
        full[free], std[free] = x, std_free
        return AccelCalibration.from_fit(full, std, free, fun, "; ".join([*tried, note] if note else tried))
    raise AccelCalibrationError(
        "the rests cannot calibrate the accelerometer: their orientations are too alike"
        + (f" ({'; '.join(tried)})" if tried else "")
        + ". Rest the device in more orientations (each face and edge down, a few seconds each)")


def rest_spans(stills: list[Stage], fs: float) -> list[tuple[int, int]]:
    """The samples [i, j) of each still that its accelerometer mean is taken over: ``REST_TRIM_S`` left out at
    each end, less for a still too short for that (always at least one sample, inside the still)."""
    trim = int(round(REST_TRIM_S * fs))
    out = []
    for st in stills:
        t = min(trim, max(0, (st.end - st.start - 1) // 2))
        out.append((st.start + t, st.end - t))
    return out


def rest_means(rec: Recording, stills: list[Stage]) -> np.ndarray:
    """Mean accelerometer reading (g) of each still long enough to be trusted (``rest_spans``, ``MIN_REST_SAMPLES``)."""
    if rec.accel is None:
        raise AccelCalibrationError("the recording has no accelerometer channel")
    spans = [(i, j) for i, j in rest_spans(stills, rec.fs) if j - i >= MIN_REST_SAMPLES]
    return span_means(rec.accel, spans).reshape(-1, 3)


def calibrate_accelerometer(rec: Recording, stills: list[Stage]) -> AccelCalibration:
    """The accelerometer's calibration from a recording's stills (as ``calib.stages`` finds them)."""
    return fit_accelerometer(rest_means(rec, [s for s in stills if s.kind == "still"]))
