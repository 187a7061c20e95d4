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
NOISE_LAGS = 3  # lags of the rests' noise autocorrelation counted in the noise of means and integrals
# a channel linearly interpolated onto m times its own rate correlates readings up to 2m - 1 apart: this covers m <= 4
# (Polar's 52 Hz accelerometer onto its 208 Hz gyroscope)
INTERPOLATED_LAGS = 7


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
    # axis-major (3, R n + 1), a zero column at the end: every pass runs along one axis' readings
    x = np.zeros((3, R * n + 1))
    np.subtract(np.moveaxis(gyro, -1, 0), np.moveaxis(ref, -1, 0), out=x[:, :-1].reshape(3, R, n))
    starts = s0 + (np.arange(R) * n)[:, None]
    ends = s1 + (np.arange(R) * n)[:, None]
    edges = np.stack((starts, ends), axis=-1).reshape(-1)

    def per_still(v: np.ndarray) -> np.ndarray:
        return np.moveaxis(v.reshape(3, R, S), 0, -1)  # (R, S, 3)

    if np.all(np.diff(edges) >= 0):
        # one pass: sums over [start, end) of each still (the segments in between are dropped)
        sum1 = per_still(np.add.reduceat(x, edges, axis=1)[:, 0::2])
        sum2 = per_still(np.add.reduceat(x * x, edges, axis=1)[:, 0::2])
        hi = per_still(np.maximum.reduceat(x, edges, axis=1)[:, 0::2])
        lo = per_still(np.minimum.reduceat(x, edges, axis=1)[:, 0::2])
    else:  # overlapping or unordered windows: running sums
        c1 = np.concatenate((np.zeros((3, 1)), np.cumsum(x, axis=1)), axis=1)
        c2 = np.concatenate((np.zeros((3, 1)), np.cumsum(x * x, axis=1)), axis=1)
        sum1 = per_still(c1[:, ends] - c1[:, starts])
        sum2 = per_still(c2[:, ends] - c2[:, starts])
        window = [x[:, a:b] if b > a else np.zeros((3, 1)) for a, b in zip(starts.ravel(), ends.ravel(), strict=True)]
        hi = per_still(np.array([w.max(axis=1) for w in window]).T)
        lo = per_still(np.array([w.min(axis=1) for w in window]).T)
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
        _leave_out_knocks(x[:, r * n : (r + 1) * n], bounds[r], mean[r] - ref[r], mean[r], count[r], sigma[r])
    return mean, count, sigma


def _leave_out_knocks(x: np.ndarray, bounds: np.ndarray, centred: np.ndarray, mean: np.ndarray, count: np.ndarray,
                      sigma: np.ndarray) -> None:
    """One recording's rest statistics (``mean`` (S, 3), ``count`` (S,), ``sigma`` (3,)) recomputed in place without
    its knocks, from its readings axis-major ``x`` (3, n) and the rests' means ``centred`` (S, 3), both less the same
    reference."""
    rests = np.flatnonzero(bounds[:, 1] > bounds[:, 0])
    a, b = bounds[rests, 0].astype(np.int64), bounds[rests, 1].astype(np.int64)
    length = b - a
    first = np.concatenate(([0], np.cumsum(length)[:-1]))  # where each rest begins among the rests' samples
    # (3, samples), each sample less its rest's mean: every step below runs along contiguous rows
    d = np.concatenate([x[:, i:j] for i, j in zip(a, b, strict=True)], axis=1) - np.repeat(centred[rests].T, length, axis=1)
    devs = np.abs(d)
    scale = np.maximum(1.4826 * np.median(devs, axis=1), MIN_SIGMA_DPS)
    burst = np.flatnonzero(np.any(devs > KNOCK_SIGMA * scale[:, None], axis=0))
    if not burst.size:
        return
    # a burst's ring: every sample within KNOCK_RING of one, inside the same rest
    owner = np.searchsorted(first, burst, side="right") - 1
    ring = burst[:, None] + np.arange(-KNOCK_RING, KNOCK_RING + 1)
    inside = (ring >= first[owner, None]) & (ring < (first + length)[owner, None])
    kept = np.ones(d.shape[1], dtype=bool)
    kept[ring[inside]] = False
    n = np.add.reduceat(kept, first).astype(float)
    if np.any(n == 0):  # a rest that is all knock keeps its samples
        kept |= np.repeat(n == 0, length)
    n = np.where(n == 0, length, n)
    shift = np.add.reduceat(d * kept, first, axis=1) / n  # (3, rests): the kept samples' mean less the whole rest's
    mean[rests] += shift.T
    count[rests] = n
    ss = (((d - np.repeat(shift, length, axis=1)) ** 2) * kept).sum(axis=1)
    sigma[:] = np.maximum(np.sqrt(ss / max(float((n - 1).sum()), 1.0)), MIN_SIGMA_DPS)


def noise_colour(readings: np.ndarray, spans: list[tuple[int, int]], max_lag: int = NOISE_LAGS) -> np.ndarray:
    """Per axis, 1 + 2 sum of the rests' noise autocorrelation over lags 1..max_lag: how much more a mean or an
    integral over many samples scatters than white noise of the same per-sample spread would (1 for white noise;
    a sensor's internal low-pass filter, or readings interpolated from a slower channel, make it larger).
    ``readings`` (n, 3): a gyroscope's or an accelerometer's; ``spans``: the rests' samples [i, j). A knock's burst
    (beyond ``KNOCK_SIGMA`` robust standard deviations, with its ring) is left out, as from the rests' means."""
    n = len(readings)
    inside = np.zeros(n, dtype=bool)
    for i, j in spans:
        inside[i:j] = True
    dev = _rest_deviations(readings, spans, inside)
    spread = np.sqrt(np.mean(dev[inside] ** 2, axis=0)) if inside.any() else np.zeros(3)
    if np.any(np.abs(dev) > KNOCK_SIGMA * np.maximum(spread, MIN_SIGMA_DPS)):  # as in ``still_statistics``
        scale = np.maximum(1.4826 * np.median(np.abs(dev[inside]), axis=0), MIN_SIGMA_DPS)
        burst = inside & np.any(np.abs(dev) > KNOCK_SIGMA * scale, axis=1)
        if burst.any():
            ring = np.convolve(burst.astype(float), np.ones(2 * KNOCK_RING + 1), mode="same") > 0
            inside &= ~ring
            dev = _rest_deviations(readings, spans, inside)
    var = np.sum(dev**2, axis=0) / max(int(inside.sum()), 1)
    factor = np.ones(3)
    gaps = np.cumsum(~inside)  # equal for two samples exactly when no sample between them is outside a rest
    for k in range(1, max_lag + 1):
        pair = inside[:-k] & inside[k:] & (gaps[:-k] == gaps[k:])  # both samples of the pair in the same rest
        if pair.any():
            factor += 2.0 * np.sum(dev[:-k][pair] * dev[k:][pair], axis=0) / pair.sum() / np.maximum(var, 1e-300)
    return np.clip(factor, 0.25, 16.0)


def _rest_deviations(readings: np.ndarray, spans: list[tuple[int, int]], kept: np.ndarray) -> np.ndarray:
    """Each ``kept`` sample of a rest less the mean of its rest's kept samples; zero elsewhere."""
    dev = np.zeros(readings.shape, dtype=float)
    for i, j in spans:
        keep = kept[i:j]
        if keep.any():
            dev[i:j][keep] = readings[i:j][keep] - readings[i:j][keep].mean(axis=0)
    return dev


def rest_colour(readings: np.ndarray, spans: list[tuple[int, int]], max_lag: int = NOISE_LAGS) -> float:
    """``noise_colour`` pooled over the three axes (one sensor, one filter) and at least 1: what a low-pass filter or
    an interpolation adds is counted, while a white sensor's estimate scattering below 1 (a few per cent over a
    session's rests) is not taken for readings better than independent."""
    return max(float(np.mean(noise_colour(readings, spans, max_lag))), 1.0)
