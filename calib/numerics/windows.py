"""Windows of readings stacked for vectorised fits, and the batched triangular solve the fits whiten with."""

from __future__ import annotations

import numpy as np


def windows(gyro: np.ndarray, bounds: np.ndarray, dt: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stack the turn windows [start, end) of R recordings time-first.

    gyro (R, n, 3); bounds (R, J, 2); dt a scalar or (R, n) per-sample intervals (s).
    Returns m (L, R*J, 3) and dt (L, R*J), zero past each window's end, L the longest window.
    """
    R, n, _ = gyro.shape
    J = bounds.shape[1]
    lengths = bounds[..., 1] - bounds[..., 0]
    L = int(lengths.max())
    offs = np.arange(L)
    idx = np.minimum(bounds[..., 0, None] + offs, n - 1)  # (R, J, L)
    inside = offs < lengths[..., None]
    rows = np.arange(R)[:, None, None]
    m = np.where(inside[..., None], gyro[rows, idx], 0.0)  # (R, J, L, 3)
    if np.ndim(dt) == 0:
        d = np.where(inside, float(dt), 0.0)
    else:
        d = np.where(inside, np.asarray(dt)[rows, idx], 0.0)
    m = np.ascontiguousarray(m.reshape(R * J, L, 3).transpose(1, 0, 2))
    d = np.ascontiguousarray(d.reshape(R * J, L).T)
    return m, d


def solve_lower(Lc: np.ndarray, x: np.ndarray) -> np.ndarray:
    """L^-1 x for batched lower-triangular L (..., 3, 3) and x (..., 3, k), by forward substitution."""
    y = np.empty_like(x)
    y[..., 0, :] = x[..., 0, :] / Lc[..., 0, 0, None]
    y[..., 1, :] = (x[..., 1, :] - Lc[..., 1, 0, None] * y[..., 0, :]) / Lc[..., 1, 1, None]
    y[..., 2, :] = (x[..., 2, :] - Lc[..., 2, 0, None] * y[..., 0, :] - Lc[..., 2, 1, None] * y[..., 1, :]) / Lc[..., 2, 2, None]
    return y
