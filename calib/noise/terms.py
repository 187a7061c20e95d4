"""The Allan variance's terms and the noise parameters read from them (IEEE Std 952, annex C).

    AVAR(tau) = N^2 / tau + K^2 tau / 3 + R^2 tau^2 / 2 + sum_j GM(tau; sigma_j, Tc_j)

N the white noise's density (angle or velocity random walk), K the rate (or acceleration) random walk, R a rate
ramp, and in place of IEEE 952's flat bias-instability term a family of first-order Gauss-Markov processes with
correlation times an octave apart across the curve (their sum is how flicker noise is built, and it also fits a
single Gauss-Markov bias, whose bump a flat term cannot follow: a flat term fitted to one claims variance at short
times that is not there, and biases N read there). IEEE 952's quantisation term (3 Q^2 / tau^2) is left out: it is
the rounding of an *angle* output; a MEMS sensor outputs rates, whose rounding is white in rate and adds to N. The
terms are fitted by non-negative weighted least squares (each point weighted by the variance its degrees of freedom
give it); the fit draws the plot's line, says where each term dominates and what noise type each point is of.

Each parameter is then **read at one averaging time**, as IEEE 952 reads the slopes, so that its 95 % interval is
the chi-squared interval of that one point (points of one curve are correlated; a fit through several would claim
more than they hold):

- N and K at the averaging time where their term is best determined: where (model / term)^2 / edf is least, among
  the times where the term is more than half of the variance; the other terms' share there (from the fit) is taken
  off the point and its band.
- B, the IEEE reading of the curve's floor: the measured deviation, over sqrt(2 ln 2 / pi), at the averaging time of
  the fitted curve's first local minimum on the octave grid (the fit chooses where, so that a point that happens to
  fall low is not chosen for it: the lowest measured point held the closed form's floor in 90.8 % of simulated
  Gauss-Markov hours, this one in 93.4 %); seen when the measured curve rises after it beyond both points' bands (a rate
  random walk, or the bump of a Gauss-Markov bias), else the floor may still fall further and only bounds B.

A term never dominant (or a floor that does not rise again) is **not seen**: the report gives the least 95 % upper
bound the curve sets on it instead of a value.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from calib.noise.allan import AllanCurve

B_FACTOR = float(np.sqrt(2.0 * np.log(2.0) / np.pi))  # 0.664: the flicker floor's deviation over B
WHITE, RANDOM_WALK, RAMP = 0, 1, 2  # the first columns of the basis; the Gauss-Markov family follows
DOMINANT = 0.5  # a term is read only where it is more than this share of the variance


def gauss_markov_avar(tau_s: np.ndarray, tc_s: np.ndarray) -> np.ndarray:
    """(T, J): the Allan variance of a first-order Gauss-Markov process of unit standard deviation and correlation
    time ``tc_s`` (its autocorrelation e^(-|t|/Tc)): (2 Tc / tau) (1 - (Tc / (2 tau)) (3 - 4 e^(-tau/Tc) + e^(-2 tau/Tc)))."""
    r = np.asarray(tau_s, float)[:, None] / np.asarray(tc_s, float)[None, :]
    return (2.0 / r) * (1.0 - (3.0 - 4.0 * np.exp(-r) + np.exp(-2.0 * r)) / (2.0 * r))


@dataclass(frozen=True)
class TermFit:
    """The fitted terms: N, K, R and the Gauss-Markov family's standard deviations at correlation times ``tc_s``."""

    tc_s: np.ndarray  # (J,)
    coefficients: np.ndarray  # (3 + J,): N, K, R, sigma_1..sigma_J

    def parts(self, tau_s: np.ndarray) -> np.ndarray:
        """(T, 3 + J): each term's Allan variance at ``tau_s``."""
        return basis(tau_s, self.tc_s) * self.coefficients**2

    def adev(self, tau_s: np.ndarray) -> np.ndarray:
        """The fitted curve's deviation at ``tau_s``."""
        return np.sqrt(self.parts(tau_s).sum(axis=1))

    def type_shares(self, tau_s: np.ndarray) -> np.ndarray:
        """(T, 3): the share of each point's variance that is white, flicker and random-walk rate noise (a
        Gauss-Markov process is a random walk well within its correlation time, white well beyond it)."""
        tau = np.asarray(tau_s, float)
        parts = self.parts(tau)
        r = tau[:, None] / self.tc_s[None, :]
        gm = parts[:, 3:]
        shares = np.column_stack([parts[:, WHITE] + (gm * (r > 2)).sum(axis=1), (gm * ((r >= 0.5) & (r <= 2))).sum(axis=1),
                                  parts[:, RANDOM_WALK] + parts[:, RAMP] + (gm * (r < 0.5)).sum(axis=1)])
        total = shares.sum(axis=1, keepdims=True)
        return np.where(total > 0, shares / np.where(total > 0, total, 1.0), np.array([1.0, 0.0, 0.0]))

    def to_json(self) -> dict[str, Any]:
        """N, K, R and the Gauss-Markov processes the fit kept."""
        c = self.coefficients
        return {"white": float(c[WHITE]), "random_walk": float(c[RANDOM_WALK]), "ramp": float(c[RAMP]),
                "gauss_markov": [{"tc_s": float(t), "sigma": float(v)} for t, v in zip(self.tc_s, c[3:], strict=True) if v > 0]}


def basis(tau_s: np.ndarray, tc_s: np.ndarray) -> np.ndarray:
    """(T, 3 + J): each term's Allan variance for a coefficient of 1."""
    tau = np.asarray(tau_s, float)[:, None]
    return np.hstack([1.0 / tau, tau / 3.0, tau**2 / 2.0, gauss_markov_avar(tau[:, 0], tc_s)])


def fit_terms(curve: AllanCurve) -> TermFit:
    """The terms fitted to the curve by non-negative least squares, each point weighted by its degrees of freedom
    (the relative variance of an Allan variance with e degrees of freedom is 2/e). The Gauss-Markov correlation
    times run an octave apart from twice the shortest averaging time to a quarter of the longest: a shorter one is
    white noise on the whole curve, a longer one a random walk."""
    from scipy.optimize import nnls

    tau = curve.tau_s
    tc = tau[(tau >= 2 * tau[0]) & (tau <= tau[-1] / 4)]
    A = basis(tau, tc)
    model = curve.avar.copy()
    squares = np.zeros(A.shape[1])
    for _ in range(3):  # weights from the model once there is one: a point that happens to fall low is not trusted more
        w = np.sqrt(curve.edf / 2.0) / np.maximum(model, 1e-300)
        squares, _ = nnls(A * w[:, None], curve.avar * w, maxiter=50 * A.shape[1])
        model = np.maximum(A @ squares, 1e-300)
    return TermFit(tc, np.sqrt(squares))


@dataclass(frozen=True)
class Reading:
    """One noise parameter read from a curve: its value with a 95 % interval (seen), or only an upper bound (not
    seen), the averaging time it was read at and the range where its term dominates."""

    name: str
    seen: bool
    value: float | None
    lo95: float | None
    hi95: float
    tau_s: float
    tau_range_s: tuple[float, float] | None

    @property
    def shown(self) -> float:
        """The value when seen, else the upper bound: what a plot or a single-number file shows."""
        return self.hi95 if self.value is None else self.value

    def to_json(self) -> dict[str, Any]:
        """The reading as JSON: value and ci95 when seen, upper95 otherwise."""
        return {"seen": self.seen, "value": self.value, "ci95": None if not self.seen else [self.lo95, self.hi95],
                "upper95": None if self.seen else self.hi95, "tau_s": self.tau_s,
                "tau_range_s": None if self.tau_range_s is None else list(self.tau_range_s)}


def _range(tau: np.ndarray, mask: np.ndarray) -> tuple[float, float] | None:
    return None if not mask.any() else (float(tau[mask].min()), float(tau[mask].max()))


def read_slope(curve: AllanCurve, fit: TermFit, term: int, name: str) -> Reading:
    """N (``WHITE``) or K (``RANDOM_WALK``) read at the averaging time that determines it best (module docstring)."""
    parts = fit.parts(curve.tau_s)
    model = np.maximum(parts.sum(axis=1), 1e-300)
    own = parts[:, term]
    others = model - own
    dominant = own > DOMINANT * model
    unit = basis(curve.tau_s, fit.tc_s)[:, term]
    if not dominant.any():
        bound = curve.hi95 / np.sqrt(unit)
        i = int(np.argmin(bound))
        return Reading(name, False, None, None, float(bound[i]), float(curve.tau_s[i]), None)
    cost = np.where(dominant, (model / np.maximum(own, 1e-300)) ** 2 / curve.edf, np.inf)
    i = int(np.argmin(cost))
    value, lo, hi = (np.sqrt(max(v**2 - others[i], 0.0) / unit[i]) for v in (curve.adev[i], curve.lo95[i], curve.hi95[i]))
    return Reading(name, True, float(value), float(lo), float(hi), float(curve.tau_s[i]), _range(curve.tau_s, dominant))


def read_floor(curve: AllanCurve, fit: TermFit) -> Reading:
    """B: the measured deviation at the fitted curve's first local minimum over sqrt(2 ln 2 / pi), seen when the
    measured curve rises beyond it."""
    d, lo, hi = curve.adev, curve.lo95, curve.hi95
    f = fit.adev(curve.tau_s)
    for i in range(1, d.size - 1):
        if f[i] < f[i - 1] and f[i] <= f[i + 1] and np.any(lo[i + 1:] > hi[i]):
            near = np.flatnonzero(lo <= hi[i])  # the times whose deviation cannot be told from the floor's, around it
            run = near[(near >= i) | (near <= i)]
            first, last = i, i
            while first - 1 in run:
                first -= 1
            while last + 1 in run:
                last += 1
            return Reading("bias_instability", True, float(d[i] / B_FACTOR), float(lo[i] / B_FACTOR), float(hi[i] / B_FACTOR),
                           float(curve.tau_s[i]), (float(curve.tau_s[first]), float(curve.tau_s[last])))
    j = int(np.argmin(hi))
    return Reading("bias_instability", False, None, None, float(hi[j] / B_FACTOR), float(curve.tau_s[j]), None)
