"""The rests' statistics: each rest's mean and length, and the reading noise pooled over the rests."""

from __future__ import annotations

import numpy as np

MIN_SIGMA_DPS = 1e-6  # floor for noise-free data, so that the weights stay finite


def still_statistics(gyro: np.ndarray, bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean (R, S, 3), sample count (R, S) and pooled within-still std (R, 3) of still windows (R, S, 2).

    Windows with end <= start count as absent. The std pools every still's deviations from its own
    mean, so offsets that differ between stills do not inflate it.
    """
    R, n, _ = gyro.shape
    S = bounds.shape[1]
    s0 = bounds[..., 0]
    s1 = np.maximum(bounds[..., 1], s0)
    count = (s1 - s0).astype(float)
    ref = gyro[:, :1, :]  # subtracting a reference keeps the sums of squares well conditioned
    x = (gyro - ref).reshape(R * n, 3)
    starts = s0 + (np.arange(R) * n)[:, None]
    ends = s1 + (np.arange(R) * n)[:, None]
    edges = np.stack((starts, ends), axis=-1).reshape(-1)
    if np.all(np.diff(edges) >= 0):
        # one pass: sums over [start, end) of each still (the segments in between are dropped)
        x = np.concatenate((x, np.zeros((1, 3))))
        sum1 = np.add.reduceat(x, edges, axis=0)[0::2].reshape(R, S, 3)
        sum2 = np.add.reduceat(x * x, edges, axis=0)[0::2].reshape(R, S, 3)
    else:  # overlapping or unordered windows: running sums
        c1 = np.concatenate((np.zeros((1, 3)), np.cumsum(x, axis=0)))
        c2 = np.concatenate((np.zeros((1, 3)), np.cumsum(x * x, axis=0)))
        sum1 = c1[ends] - c1[starts]
        sum2 = c2[ends] - c2[starts]
    empty = count == 0
    sum1[empty] = 0.0
    sum2[empty] = 0.0
    safe = np.maximum(count, 1.0)[..., None]
    mean = sum1 / safe
    ss = np.maximum(sum2 - sum1 * mean, 0.0)  # sum of squared deviations per still
    pooled_dof = np.maximum(count - 1.0, 0.0).sum(axis=1)
    sigma = np.sqrt(ss.sum(axis=1) / np.maximum(pooled_dof, 1.0)[:, None])
    sigma = np.maximum(sigma, MIN_SIGMA_DPS)
    return mean + ref, count, sigma
