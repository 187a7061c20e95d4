"""Weighted linear fits of a watch: the rows already whitened (unit variance, uncorrelated), an extra variance for
scatter beyond the stated noise, and the best single step in time with its significance."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

Z_MOVED = 4.0  # a change is told from noise beyond this many standard deviations (before the search over steps)


@dataclass(frozen=True)
class LinearFit:
    """Parameters ``x`` with covariance ``cov`` (scaled up by the Birge ratio when the rows scatter more than their
    stated noise), chi-square and degrees of freedom."""

    x: np.ndarray
    cov: np.ndarray
    chi2: float
    dof: int

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))


def fit(A: np.ndarray, y: np.ndarray) -> LinearFit:
    """Least squares of whitened rows ``A x = y``."""
    x, *_ = np.linalg.lstsq(A, y, rcond=None)
    res = y - A @ x
    chi2 = float(res @ res)
    dof = max(A.shape[0] - A.shape[1], 0)
    cov = _covariance(A.T @ A)
    if dof > 0 and chi2 > dof:
        cov = cov * (chi2 / dof)
    return LinearFit(x, cov, chi2, dof)


def _covariance(info: np.ndarray) -> np.ndarray:
    """The inverse of the information matrix; a parameter the rows do not determine (alone or with others) gets an
    infinite variance, never the zero a pseudo-inverse would give it."""
    lam, V = np.linalg.eigh(info)
    small = lam <= 1e-10 * max(float(lam.max()), 1e-300)
    cov = (V / np.where(small, np.inf, lam)) @ V.T
    if small.any():
        touched = np.any(np.abs(V[:, small]) > 1e-6, axis=1)
        cov[np.ix_(touched, touched)] = np.inf
    return cov


def extra_variance(A: np.ndarray, y: np.ndarray, var: np.ndarray) -> float:
    """The variance to add to every row's ``var`` so that the fit's chi-square per degree of freedom is 1 (0 when the
    rows scatter no more than stated): a rest's bias wanders a little on its own, beyond its mean's noise."""
    dof = A.shape[0] - A.shape[1]
    if dof <= 0:
        return 0.0

    def excess(extra: float) -> float:
        w = 1.0 / np.sqrt(var + extra)
        return fit(A * w[:, None], y * w).chi2 - dof

    if excess(0.0) <= 0.0:
        return 0.0
    lo, hi = 0.0, float(np.var(y)) + float(np.max(var))
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if excess(mid) > 0.0 else (lo, mid)
    return hi


@dataclass(frozen=True)
class Step:
    """A step of ``size`` +- ``std`` from group ``at`` on (the rows of groups before it keep the model without it);
    ``delta_chi2``: how much better the fit is with it."""

    at: int
    size: float
    std: float
    delta_chi2: float


def correlation_inflation(res: np.ndarray) -> float:
    """How much more a fit's parameters scatter than its rows' independence claims, from its whitened residuals'
    lag-1 autocorrelation in time order (an AR(1) process's (1 + rho) / (1 - rho); 1 when they do not correlate): a
    sensor's bias wanders slowly, so consecutive rests share their errors."""
    if res.size < 3:
        return 1.0
    rho = float(res[:-1] @ res[1:] / max(float(res @ res), 1e-300))
    rho = min(max(rho, 0.0), 0.95)
    return (1.0 + rho) / (1.0 - rho)


def best_step(A: np.ndarray, y: np.ndarray, base: np.ndarray, groups: np.ndarray, min_side: int = 2,
              correlated: bool = False, always: bool = False) -> Step | None:
    """The single step of the column ``base`` (a row's sensitivity to the parameter that may have stepped) that most
    improves the whitened fit, over every split of the ordered ``groups`` with at least ``min_side`` groups each side;
    None unless it is significant after the search (Z_MOVED, Bonferroni over the splits). ``correlated``: the rows'
    errors may correlate in time (a wandering bias): the gain is shrunk and the step's std widened by the residuals'
    ``correlation_inflation`` with the step in the model. ``always``: the likeliest step, significant or not."""
    splits = np.unique(groups)[min_side:-min_side + 1] if min_side > 1 else np.unique(groups)[1:]
    if splits.size == 0:
        return None
    chi0 = fit(A, y).chi2
    best: tuple[float, int, LinearFit, np.ndarray] | None = None
    for s in splits:
        design = np.column_stack([A, base * (groups >= s)])
        f = fit(design, y)
        if best is None or chi0 - f.chi2 > best[0]:
            best = (chi0 - f.chi2, int(s), f, design)
    assert best is not None
    gain, at, f, design = best
    inflation = correlation_inflation(y - design @ f.x) if correlated else 1.0
    threshold = Z_MOVED**2 + 2.0 * np.log(splits.size)
    if gain / inflation < threshold and not always:
        return None
    return Step(at, float(f.x[-1]), float(f.std[-1]) * np.sqrt(inflation), gain / inflation)
