"""The tail probabilities and quantiles the estimators and the model check test with (chi-square, F, normal).

They are scipy.special's functions, which scipy.stats wraps: importing scipy.stats costs about a second and a half of
every process's start (the service, each of its compute workers, each command), and these four are all gyrocal uses.
Each takes numbers or arrays and returns an array (0-d for numbers).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike


def chi2_sf(x: ArrayLike, df: ArrayLike) -> np.ndarray:
    """P(X > x) for X ~ chi-square with ``df`` degrees of freedom."""
    return np.asarray(_special().chdtrc(df, x))


def chi2_isf(q: ArrayLike, df: ArrayLike) -> np.ndarray:
    """The x with P(X > x) = q, for X ~ chi-square with ``df`` degrees of freedom."""
    return np.asarray(_special().chdtri(df, q))


def f_sf(x: ArrayLike, dfn: ArrayLike, dfd: ArrayLike) -> np.ndarray:
    """P(X > x) for X ~ F(dfn, dfd)."""
    return np.asarray(_special().fdtrc(dfn, dfd, x))


def norm_sf(z: ArrayLike) -> np.ndarray:
    """P(Z > z) for Z standard normal."""
    return np.asarray(_special().ndtr(-np.asarray(z, dtype=float)))


def _special() -> Any:
    """scipy.special, imported when first needed: importing it costs a third of a second, which a command that
    computes nothing (``gyrocal --help``, ``gyrocal operator add``) need not pay."""
    from scipy import special

    return special
