"""The time base: lost samples (sample counter, timestamps) and the sample clock (device vs host time).

Model of the time base. The device samples every P = 1 / fs seconds of its own clock; sample n has
device time n P. Nominally every sample arrives (row i is sample n_i = n_0 + i) and the device clock
keeps true time. Two catalogued effects change that:

- sample_loss: rows are missing, n_i - n_{i-1} > 1; the counter shows it directly, timestamps stamped
  by the device show it as intervals of a whole number of periods;
- clock_error: the device clock runs at (1 + e) times true time, t_device = (1 + e) t_true, so a
  host clock receiving the samples sees them arrive every P / (1 + e) seconds.

The fit statistic of the time base is the sum of squared timestamp residuals against the model,
in units of the timestamps' own jitter (estimated from the data, at least 1e-3 of a period): before
= every row one period after the last on an exact clock, after = the effect modelled.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from calib.recording import Recording
from calib.stages.stage import Stage

JITTER_FLOOR = 0.01  # of a period: timestamps are never trusted beyond this
DEVICE_LIKE = 0.02  # timestamps whose intervals scatter less than this (of a period) are the device's own


@dataclass
class TimeBase:
    """What the counter and the timestamps say about the samples and the clock."""

    period: float  # nominal sample period, s
    stated_rate: bool  # the period comes from the stated sample rate, not from the data
    device_stamps: bool  # the timestamps are regular (stamped by the device), not host arrival times
    index: np.ndarray  # (n,) sample number of each row (counter, or whole periods of the timestamps)
    index_source: str | None  # "counter", "timestamps" or None (no way to tell)
    gaps: list[tuple[int, int, float]] = field(default_factory=list)  # (row after the gap, samples missing, time s)
    lost: int = 0
    loss_fit: tuple[float, float] | None = None  # time-base deviance (before, after)
    clock_e: float | None = None  # device clock rate error e (fraction)
    clock_std: float | None = None
    clock_fit: tuple[float, float] | None = None
    host: bool = False  # an outside clock (host arrival times) was available

    def summary(self) -> dict:
        return {
            "period_s": self.period,
            "stated_rate": self.stated_rate,
            "device_stamps": self.device_stamps,
            "index_source": self.index_source,
            "lost_samples": self.lost,
            "gaps": len(self.gaps),
            "clock_error": self.clock_e,
            "clock_error_std": self.clock_std,
            "host_time": self.host,
        }


def _line_fit(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares line y = c0 + c1 x: coefficients and residuals."""
    A = np.column_stack((np.ones_like(x), x))
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    return coef, y - A @ coef


def analyse_timebase(rec: Recording, host_t: np.ndarray | None = None) -> TimeBase:
    """Sample loss from the counter or the timestamps, and the clock rate against host times if any."""
    t = rec.t
    d = np.diff(t)
    stated = bool(rec.meta.sample_rate_hz)
    if rec.seq is not None and rec.seq.size > 1 and np.all(np.diff(rec.seq) > 0):
        steps = np.diff(rec.seq)
        ones = steps == 1
        base = np.median(d[ones]) if ones.any() else np.median(d / steps)
    else:
        steps = None
        base = np.median(d) if d.size else 1.0
    period = 1.0 / float(rec.meta.sample_rate_hz) if stated and rec.meta.sample_rate_hz else float(base)
    rel = d / period if d.size else np.zeros(0)
    # regular timestamps: the intervals are whole numbers of periods up to a small scatter
    frac = np.abs(rel - np.round(rel)) if rel.size else np.zeros(0)
    device_stamps = bool(rel.size) and float(np.median(frac)) < DEVICE_LIKE and np.all(np.round(rel) >= 1)

    if steps is not None:
        index = np.concatenate(([0], np.cumsum(steps)))
        source = "counter"
    elif device_stamps:
        index = np.concatenate(([0], np.cumsum(np.maximum(1, np.round(rel).astype(np.int64)))))
        source = "timestamps"
    else:
        index = np.arange(t.size)
        source = None
    tb = TimeBase(period, stated, bool(device_stamps), index, source)
    jumps = np.flatnonzero(np.diff(index) > 1)
    tb.gaps = [(int(i + 1), int(index[i + 1] - index[i] - 1), float(t[i + 1] - t[0])) for i in jumps]
    tb.lost = int(sum(g[1] for g in tb.gaps))
    if tb.lost and source is not None:
        tb.loss_fit = _loss_deviance(t, index, period)

    clock = host_t if host_t is not None else (t if (steps is not None and not device_stamps) else None)
    if clock is not None and stated and source is not None:
        _clock(tb, np.asarray(clock, dtype=float), index)
    return tb


def _jitter(resid: np.ndarray, period: float) -> float:
    """Robust scale of timestamp residuals (s), floored at JITTER_FLOOR periods."""
    if resid.size < 3:
        return JITTER_FLOOR * period
    s = 1.4826 * float(np.median(np.abs(resid - np.median(resid))))
    return max(s, JITTER_FLOOR * period)


def _loss_deviance(t: np.ndarray, index: np.ndarray, period: float) -> tuple[float, float]:
    """Time-base deviance without (rows consecutive) and with the lost samples (rows at their sample numbers)."""
    rows = np.arange(t.size, dtype=float)
    _, r_after = _line_fit(index.astype(float), t)
    sj = _jitter(np.diff(r_after), period) / np.sqrt(2.0)
    r_before = t - t[0] - rows * period
    r_before -= r_before.mean()
    r_after = t - t[0] - index * period
    r_after -= r_after.mean()
    return float(np.sum((r_before / sj) ** 2)), float(np.sum((r_after / sj) ** 2))


def _clock(tb: TimeBase, host: np.ndarray, index: np.ndarray) -> None:
    """Sample period on the host clock: host_i = c + index_i P / (1 + e) + delay jitter."""
    tb.host = True
    x = index.astype(float)
    # delays are one-sided (a sample cannot arrive before it was taken): fit the line, then refit to
    # the lower half of the residuals, which follows the sampling times more closely
    coef, r = _line_fit(x, host)
    low = r <= np.median(r)
    if low.sum() >= 10:
        coef, _ = _line_fit(x[low], host[low])
        r = host - (coef[0] + coef[1] * x)
    P_host = float(coef[1])
    e = tb.period / P_host - 1.0
    sj = _jitter(r, tb.period)
    sxx = float(np.sum((x - x.mean()) ** 2))
    std_slope = sj / np.sqrt(max(sxx, 1e-300))
    tb.clock_e = e
    tb.clock_std = float(std_slope * tb.period / P_host**2)
    # deviance: host times against the nominal clock (slope P) and against the fitted one
    r_nom = host - x * tb.period
    r_nom -= np.median(r_nom)
    r_fit = r - np.median(r)
    tb.clock_fit = (float(np.sum((r_nom / sj) ** 2)), float(np.sum((r_fit / sj) ** 2)))


def bridge(rec: Recording, tb: TimeBase) -> Recording:
    """The recording with every lost sample put back, interpolated at its sample number.

    Gyro readings follow a cubic spline through the delivered samples (hand motion is smooth over a
    few samples, so holding the last reading over a gap would add a turn-dependent error); the other
    channels are interpolated linearly; times and counter follow the sample numbers.
    """
    from scipy.interpolate import CubicSpline

    idx = tb.index.astype(float)
    full = np.arange(int(tb.index[0]), int(tb.index[-1]) + 1, dtype=float)
    def lin(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else np.interp(full, idx, a)

    gyro = CubicSpline(idx, rec.gyro, axis=0)(full)
    accel = None if rec.accel is None else np.column_stack([np.interp(full, idx, rec.accel[:, i]) for i in range(3)])
    seq = None if rec.seq is None else (rec.seq[0] + (full - full[0])).astype(np.int64)
    return replace(rec, t=np.interp(full, idx, rec.t), gyro=gyro, accel=accel, seq=seq, temp=lin(rec.temp),
                   host_t=lin(getattr(rec, "host_t", None)))


def on_bridged_rows(stage: Stage, tb: TimeBase) -> Stage:
    """``stage`` of the delivered rows, at its rows of the recording ``bridge`` gives (times are unchanged)."""
    first = int(tb.index[0])
    return replace(stage, start=int(tb.index[stage.start]) - first, end=int(tb.index[stage.end - 1]) - first + 1)
