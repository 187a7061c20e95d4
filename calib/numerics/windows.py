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


def span_means(x: np.ndarray, spans: np.ndarray | list[tuple[int, int]]) -> np.ndarray:
    """Means of x (n, k) over the spans [start, end) (S, 2) of its rows: (S, k), NaN for an empty span. One pass when
    the spans are in order and do not overlap (a recording's rests)."""
    spans = np.asarray(spans, dtype=np.int64).reshape(-1, 2)
    count = spans[:, 1] - spans[:, 0]
    if spans.shape[0] == 0:
        return np.zeros((0,) + x.shape[1:])
    edges = spans.ravel()
    if np.all(count > 0) and np.all(np.diff(edges) >= 0) and edges[0] >= 0:
        tail = edges[-1] >= x.shape[0]  # reduceat takes no index past the end: the last span then runs to it
        sums = np.add.reduceat(x, edges[:-1] if tail else edges, axis=0)[::2]
    else:
        c = np.concatenate((np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)))
        sums = c[np.clip(spans[:, 1], 0, x.shape[0])] - c[np.clip(spans[:, 0], 0, x.shape[0])]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where((count > 0).reshape((-1,) + (1,) * (x.ndim - 1)), sums / count.reshape((-1,) + (1,) * (x.ndim - 1)), np.nan)


def solve_lower(Lc: np.ndarray, x: np.ndarray) -> np.ndarray:
    """L^-1 x for batched lower-triangular L (..., 3, 3) and x (..., 3, k), by forward substitution."""
    y = np.empty_like(x)
    y[..., 0, :] = x[..., 0, :] / Lc[..., 0, 0, None]
    y[..., 1, :] = (x[..., 1, :] - Lc[..., 1, 0, None] * y[..., 0, :]) / Lc[..., 1, 1, None]
    y[..., 2, :] = (x[..., 2, :] - Lc[..., 2, 0, None] * y[..., 0, :] - Lc[..., 2, 1, None] * y[..., 1, :]) / Lc[..., 2, 2, None]
    return y
