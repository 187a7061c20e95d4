"""The rests' statistics: each rest's mean and length, and the reading noise pooled over the rests.

A rest that begins as the device is put down can hold the knock of it (``calib.effects.impacts``): a short burst
far above the noise. Samples beyond ``KNOCK_SIGMA`` robust standard deviations (from the median absolute deviation)
of their rest's mean, and ``KNOCK_RING`` samples on either side, are left out of that rest, so that one knock does
not widen the noise of every rest and every turn."""

from __future__ import annotations

import numpy as np

MIN_SIGMA_DPS = 1e-6  # floor for noise-free data, so that the weights stay finite
KNOCK_SIGMA = 5.0  # a rest's sample this many robust standard deviations from its mean is a knock, not noise
KNOCK_RING = 5  # samples on either side of a knock's that still ring


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
        hi = np.maximum.reduceat(x, edges, axis=0)[0::2].reshape(R, S, 3)
        lo = np.minimum.reduceat(x, edges, axis=0)[0::2].reshape(R, S, 3)
    else:  # overlapping or unordered windows: running sums
        c1 = np.concatenate((np.zeros((1, 3)), np.cumsum(x, axis=0)))
        c2 = np.concatenate((np.zeros((1, 3)), np.cumsum(x * x, axis=0)))
        sum1 = c1[ends] - c1[starts]
        sum2 = c2[ends] - c2[starts]
        window = [[x[a:b] if b > a else np.zeros((1, 3)) for a, b in zip(sa, sb, strict=True)] for sa, sb in zip(starts, ends, strict=True)]
        hi = np.array([[w.max(axis=0) for w in row] for row in window]).reshape(R, S, 3)
        lo = np.array([[w.min(axis=0) for w in row] for row in window]).reshape(R, S, 3)
    empty = count == 0
    sum1[empty] = 0.0
    sum2[empty] = 0.0
    safe = np.maximum(count, 1.0)[..., None]
    mean = sum1 / safe
    ss = np.maximum(sum2 - sum1 * mean, 0.0)  # sum of squared deviations per still
    pooled_dof = np.maximum(count - 1.0, 0.0).sum(axis=1)
    sigma = np.sqrt(ss.sum(axis=1) / np.maximum(pooled_dof, 1.0)[:, None])
    sigma = np.maximum(sigma, MIN_SIGMA_DPS)
    # a recording has a knock where some rest's sample lies beyond KNOCK_SIGMA of its mean (the common case: none)
    farthest = np.where(empty[..., None], 0.0, np.maximum(hi - mean, mean - lo))
    knocked = np.any(farthest > KNOCK_SIGMA * sigma[:, None, :], axis=(1, 2))
    mean = mean + ref
    for r in np.flatnonzero(knocked):
        _leave_out_knocks(gyro[r], bounds[r], mean[r], count[r], sigma[r])
    return mean, count, sigma


def _leave_out_knocks(gyro: np.ndarray, bounds: np.ndarray, mean: np.ndarray, count: np.ndarray, sigma: np.ndarray) -> None:
    """One recording's rest statistics (``mean`` (S, 3), ``count`` (S,), ``sigma`` (3,)) recomputed in place without
    its knocks."""
    rests = np.flatnonzero(bounds[:, 1] > bounds[:, 0])
    a, b = bounds[rests, 0].astype(np.int64), bounds[rests, 1].astype(np.int64)
    length = b - a
    first = np.concatenate(([0], np.cumsum(length)[:-1]))  # where each rest begins among the rests' samples
    owner = np.repeat(np.arange(rests.size), length)
    start = first[owner]
    pos = np.arange(length.sum()) - start  # index of each sample inside its rest
    # axis-major (3, samples), each sample less its rest's mean: every step below runs along contiguous rows
    d = np.concatenate([gyro[i:j] for i, j in zip(a, b, strict=True)]).T - np.repeat(mean[rests].T, length, axis=1)
    devs = np.abs(d)
    scale = np.maximum(1.4826 * np.median(devs, axis=1), MIN_SIGMA_DPS)
    burst = np.any(devs > KNOCK_SIGMA * scale[:, None], axis=0)
    # a burst's ring: every sample within KNOCK_RING of one, inside the same rest
    ring = np.concatenate(([0], np.cumsum(burst)))
    lo = start + np.maximum(pos - KNOCK_RING, 0)
    hi = start + np.minimum(pos + KNOCK_RING + 1, length[owner])
    kept = (ring[hi] - ring[lo]) == 0
    n = np.add.reduceat(kept, first).astype(float)
    kept |= (n == 0)[owner]  # a rest that is all knock keeps its samples
    n = np.where(n == 0, length, n)
    shift = np.add.reduceat(d * kept, first, axis=1) / n  # (3, rests): the kept samples' mean less the whole rest's
    mean[rests] += shift.T
    count[rests] = n
    ss = (((d - np.repeat(shift, length, axis=1)) ** 2) * kept).sum(axis=1)
    sigma[:] = np.maximum(np.sqrt(ss / max(float((n - 1).sum()), 1.0)), MIN_SIGMA_DPS)
