"""The tail probabilities and quantiles the estimators and the model check test with (chi-square, F, normal, Student-t).

They are scipy.special's functions, which scipy.stats wraps: importing scipy.stats costs about a second and a half of
every process's start (the service, each of its compute workers, each command), and these five are all gyrocal uses.
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


def t_isf(q: ArrayLike, df: ArrayLike) -> np.ndarray:
    """The x with P(T > x) = q, for T ~ Student-t with ``df`` degrees of freedom (inf: normal)."""
    return np.asarray(_special().stdtrit(df, 1.0 - np.asarray(q, dtype=float)))


def t_dof(p: ArrayLike, x: ArrayLike) -> np.ndarray:
    """The degrees of freedom (>= 1) of the Student-t whose p-quantile is x (p > 0.5); inf where a normal's
    p-quantile is already x or more."""
    x = np.asarray(x, dtype=float)
    z = -_special().ndtri(1.0 - np.asarray(p, dtype=float))
    with np.errstate(invalid="ignore"):
        df = np.where(x > z, _special().stdtridf(p, np.maximum(x, z)), np.inf)
    return np.maximum(np.nan_to_num(df, nan=np.inf), 1.0)


def _special() -> Any:
    """scipy.special, imported when first needed: importing it costs a third of a second, which a command that
    computes nothing (``gyrocal --help``, ``gyrocal operator add``) need not pay."""
    from scipy import special

    return special
