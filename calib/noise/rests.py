"""The rests' statistics: each rest's mean and length, the reading noise pooled over the rests, and its colour.

A rest that begins as the device is put down can hold the knock of it (``calib.effects.impacts``): a short burst
far above the noise. Samples beyond ``KNOCK_SIGMA`` robust standard deviations (from the median absolute deviation)
of their rest's mean, and ``KNOCK_RING`` samples on either side, are left out of that rest, so that one knock does
not widen the noise of every rest and every turn. The colour (how much more a mean over many readings scatters than
their spread says, ``noise_colour``) leaves out a burst the same way, its scale the spread of the readings within
``KNOCK_SIGMA`` of theirs (one pass of clipping, a fraction of a median's cost: it runs in every calibration)."""

from __future__ import annotations

from dataclasses import dataclass

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
    (beyond ``KNOCK_SIGMA`` standard deviations of the readings without it, with its ring) is left out, as from the
    rests' means."""
    return _axis_colours(_lag_terms([readings], spans, max_lag)[0])


@dataclass(frozen=True)
class RestReadings:
    """One sensor's readings over the rests, a knock's burst left out: each rest's mean (S, 3) and how many readings
    it holds (S,), their pooled per-sample spread (3,) and its colour (``sensor_rests``)."""

    means: np.ndarray
    counts: np.ndarray
    spread: np.ndarray
    colour: float


def sensor_rests(readings: np.ndarray, spans: list[tuple[int, int]], max_lag: int = NOISE_LAGS) -> RestReadings:
    """One sensor's ``RestReadings`` over the rests ``spans``; its colour ``noise_colour`` pooled over the three axes
    (one sensor, one filter) and at least 1: what a low-pass filter or an interpolation adds is counted, while a white
    sensor's estimate scattering below 1 (a few per cent over a session's rests) is not taken for readings better
    than independent."""
    return _sensor(*_lag_terms([readings], spans, max_lag), 0)


def recordings_colours(readings: np.ndarray, spans: list[tuple[int, int]], max_lag: int = NOISE_LAGS) -> np.ndarray:
    """``sensor_rests``' colour of each of R recordings of one sensor, (R, n, 3), over the same rests, in one pass:
    (R,). A knock in one recording leaves those samples out of all (they are replays of one session)."""
    return _pooled(_axis_colours(_lag_terms(list(np.asarray(readings, dtype=float)), spans, max_lag)[0]))


def rest_readings(gyro: np.ndarray, accel: np.ndarray | None, spans: list[tuple[int, int]]
                  ) -> tuple[RestReadings, RestReadings | None]:
    """The gyroscope's (colour over ``NOISE_LAGS``) and the accelerometer's (over ``INTERPOLATED_LAGS``: it may be a
    slower channel interpolated) rest readings, in one pass over the rests ``spans`` (each [i, j) non-empty); None
    for no accelerometer."""
    if accel is None:
        return sensor_rests(gyro, spans), None
    # the gyro's rows hold NOISE_LAGS terms, the others 0
    measured = _lag_terms([gyro, accel], spans, INTERPOLATED_LAGS, rows_beyond=3)
    return _sensor(*measured, 0), _sensor(*measured, 1)


def _sensor(terms: np.ndarray, means: np.ndarray, counts: np.ndarray, spread: np.ndarray, c: int) -> RestReadings:
    """Channel ``c``'s ``RestReadings`` from ``_lag_terms``'s rows; its colour pooled over its axes, at least 1."""
    rows = slice(3 * c, 3 * c + 3)
    return RestReadings(means[rows].T, counts, spread[rows], float(_pooled(_axis_colours(terms[rows]))[0]))


def _axis_colours(terms: np.ndarray) -> np.ndarray:
    """Each row's colour, 1 + its ``_lag_terms``, within bounds a few rests' scatter cannot pass."""
    return np.clip(1.0 + terms.sum(axis=1), 0.25, 16.0)


def _pooled(colours: np.ndarray) -> np.ndarray:
    """Each channel's colour (rows of three axes) pooled over its axes, at least 1 (``sensor_rests``)."""
    return np.maximum(colours.reshape(-1, 3).mean(axis=1), 1.0)


def _lag_terms(channels: list[np.ndarray], spans: list[tuple[int, int]], max_lag: int, rows_beyond: int = 0
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """2 rho_k of each axis of ``channels`` (each (n, 3)) over the rests ``spans``, lags 1..max_lag: (3 per channel,
    max_lag), with each rest's mean (rows, S), its kept readings' count (S,) and each row's pooled spread (rows,); a
    knock in any channel leaves out those samples of all. Beyond ``NOISE_LAGS`` only the rows from ``rows_beyond`` on
    are computed (the others 0)."""
    rows = 3 * len(channels)
    spans = [(int(i), int(j)) for i, j in spans if j > i]
    if not spans:
        return np.zeros((rows, max_lag)), np.zeros((rows, 0)), np.zeros(0), np.full(rows, MIN_SIGMA_DPS)
    lengths = np.array([j - i for i, j in spans])
    at = np.concatenate([np.arange(i, j) for i, j in spans])
    # the rests' readings one after another, axis-major (rows, m): each pass runs along one row
    x = np.empty((rows, at.size))
    for c, readings in enumerate(channels):
        np.take(np.asarray(readings, dtype=float).T, at, axis=1, out=x[3 * c : 3 * c + 3])
    kept = np.ones(at.size)
    dev, means, counts = _less_rest_means(x, lengths, kept)
    sq = dev * dev
    beyond = sq > KNOCK_SIGMA**2 * np.maximum(sq.mean(axis=1), MIN_SIGMA_DPS**2)[:, None]
    if beyond.any():
        # the spread of the readings within it (one pass of clipping), the burst what lies beyond that
        within = (~beyond.any(axis=0)).astype(float)
        scale2 = np.maximum((sq @ within) / max(within.sum(), 1.0), MIN_SIGMA_DPS**2)
        burst = np.any(sq > KNOCK_SIGMA**2 * scale2[:, None], axis=0)
        if burst.any():
            # left out with its ring (wider than max_lag, so no pair spans it); their deviations count as 0
            ring = np.convolve(burst.astype(float), np.ones(2 * KNOCK_RING + 1), mode="same") > 0
            all_knock = np.add.reduceat(ring, np.concatenate(([0], np.cumsum(lengths)[:-1]))) == lengths
            kept = (~ring | np.repeat(all_knock, lengths)).astype(float)  # a rest that is all knock keeps its readings
            dev, means, counts = _less_rest_means(x, lengths, kept)
            sq = dev * dev
    ss = sq.sum(axis=1)
    spread = np.maximum(np.sqrt(ss / max(float(kept.sum()) - float(np.count_nonzero(counts)), 1.0)), MIN_SIGMA_DPS)
    var = np.maximum(ss / kept.sum(), 1e-300)  # each row's variance, the autocorrelation's scale
    ends = np.cumsum(lengths)[:-1]  # where each rest after the first begins
    terms = np.zeros((rows, max_lag))
    for k in range(1, max_lag + 1):
        # pairs k samples apart, both kept, in the same rest: all but the few across the start of a rest
        across = (ends[:, None] - np.arange(1, k + 1)).ravel()
        across = across[across >= 0]
        r = slice(0, rows) if k <= NOISE_LAGS else slice(rows_beyond, rows)
        d = dev[r]
        lagged = np.einsum("ai,ai->a", d[:, :-k], d[:, k:]) - np.einsum("ai,ai->a", d[:, across], d[:, across + k])
        count = float(kept[:-k] @ kept[k:] - kept[across] @ kept[across + k])
        if count > 0:
            terms[r, k - 1] = 2.0 * lagged / count / var[r]
    return terms, means, counts, spread


def _less_rest_means(x: np.ndarray, lengths: np.ndarray, kept: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each ``kept`` (1.0) reading of ``x`` (rows, m), the rests' readings one after another (``lengths`` each), less
    the mean of its rest's kept readings (0 for the others); those means (rows, S) and counts (S,)."""
    starts = np.concatenate(([0], np.cumsum(lengths)[:-1]))
    count = np.add.reduceat(kept, starts)
    means = np.add.reduceat(x * kept, starts, axis=1) / np.maximum(count, 1.0)
    return (x - np.repeat(means, lengths, axis=1)) * kept, means, count
