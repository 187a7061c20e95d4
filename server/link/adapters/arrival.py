"""Sample times for devices that send none: from the central's arrival times, flagged as such.

A notification's arrival time is its sending time plus a delay that is never negative and sometimes long
(the connection interval, retransmissions, a busy central), so single arrival times are not used as
sample times. The true rate is the slope of the lower envelope of arrival time against sample count: in
every second of samples the earliest arrival relative to the nominal rate is kept, and a straight line
is fitted through those minima (the least-squares slope over all arrivals until three seconds are in, the
nominal rate before 0.5 s). Delays only ever push arrivals later, so the minima sit on the sending times;
a second the central stalled through as a whole (its minimum far above the line) is left out, so a stall
does not bend the estimate. The minima's scatter about the line gives the rate's relative standard error,
which the calibrated scale factors share (every angle is a sum of readings over the rate). Samples are
spaced by the estimated rate. Without a counter, lost samples cannot be detected while the link holds;
after a reconnection the gap is estimated from the arrival times (rounded to whole samples) and reported
like any other loss: from the first arrival after it back to when the last sample before it was sent, which is the
envelope's line at that sample (its own arrival may have come late, on a busy central) once the line is fitted.
"""

from __future__ import annotations

import numpy as np

from ..base import LinkStats, SampleBatch
from ..rate_fit import RateFit

ENVELOPE_BIN_S = 1.0  # seconds of samples per bin of the lower envelope
ENVELOPE_MIN_BINS = 3
OUTLIER_SPREADS = 5.0  # a bin's minimum this many robust spreads above the line was delayed as a whole: dropped


class EnvelopeFit:
    """The rate from the lower envelope of (sample counter, arrival time): per bin of counters, the earliest
    arrival relative to the nominal rate; a least-squares line through the bins' minima."""

    def __init__(self, nominal_rate_hz: float) -> None:
        self.nominal = nominal_rate_hz
        self.bin = max(1, int(round(ENVELOPE_BIN_S * nominal_rate_hz)))
        self._minima: dict[int, tuple[int, float]] = {}  # bin -> (counter, arrival - counter / nominal)
        self._rate: float | None = None
        self._rel_std: float | None = None
        self._line: tuple[float, float] | None = None  # arrival (s after the first) = intercept + slope x counter
        self._fitted_bins = 0

    def add(self, counter: int, arrival_s: float) -> None:
        key = counter // self.bin
        lead = arrival_s - counter / self.nominal
        best = self._minima.get(key)
        if best is None or lead < best[1]:
            self._minima[key] = (counter, lead)

    def rate(self) -> float | None:
        """The envelope's rate once ENVELOPE_MIN_BINS whole bins are in, else None."""
        whole = len(self._minima) - 1  # the newest bin is still filling
        if whole < ENVELOPE_MIN_BINS:
            return None
        if whole != self._fitted_bins:
            keys = sorted(self._minima)[:-1]
            c = np.array([self._minima[k][0] for k in keys], dtype=float)
            a = np.array([self._minima[k][1] + self._minima[k][0] / self.nominal for k in keys])
            slope, slope_std, intercept = _robust_slope(c, a)
            self._rate = 1.0 / slope if slope > 0 else None
            self._rel_std = slope_std / slope if slope > 0 else None
            self._line = (intercept, slope) if slope > 0 else None
            self._fitted_bins = whole
        return self._rate

    def sent_at(self, counter: int) -> float | None:
        """When sample ``counter`` was sent (s after the first arrival), on the envelope's line: its own arrival came
        at that time or later. None while the line is not fitted."""
        if self.rate() is None or self._line is None:
            return None
        intercept, slope = self._line
        return intercept + slope * counter

    def rate_rel_std(self) -> float | None:
        """The relative standard error of ``rate()`` from the scatter of the bins' minima about their line; None
        while the rate is not fitted."""
        return self._rel_std if self.rate() is not None else None


def _robust_slope(c: np.ndarray, a: np.ndarray) -> tuple[float, float, float]:
    """Least-squares slope of ``a`` against ``c``, its standard error and the line's intercept, without the bins a
    stalled central delayed as a whole (a minimum far above the line: delays only ever push arrivals later, so only
    those are dropped)."""

    def fit(keep: np.ndarray) -> tuple[float, np.ndarray]:
        x = c[keep] - c[keep].mean()
        slope = float(x @ (a[keep] - a[keep].mean()) / (x @ x))
        return slope, a - a[keep].mean() - slope * (c - c[keep].mean())

    keep = np.ones(c.size, dtype=bool)
    slope, residual = fit(keep)
    for _ in range(3):
        centre = float(np.median(residual[keep]))
        spread = 1.4826 * float(np.median(np.abs(residual[keep] - centre)))
        late = residual > centre + OUTLIER_SPREADS * max(spread, 1e-4)
        if np.array_equal(~late, keep) or (~late).sum() < ENVELOPE_MIN_BINS:
            break
        keep = ~late
        slope, residual = fit(keep)
    x = c[keep] - c[keep].mean()
    r = residual[keep]
    intercept = float(a[keep].mean() - slope * c[keep].mean())
    return slope, float(np.sqrt(r @ r / max(1, int(keep.sum()) - 2) / (x @ x))), intercept


class ArrivalTimeline:
    """Places the samples of each notification on a time line from arrival times."""

    def __init__(self, stats: LinkStats, nominal_rate_hz: float) -> None:
        self.stats = stats
        self.nominal_rate_hz = nominal_rate_hz
        self._fit = RateFit()
        self._envelope = EnvelopeFit(nominal_rate_hz)
        self._counter = 0
        self._t_next: float | None = None  # time (s from the first sample) of the next sample
        self._arrival0: float | None = None
        self._last_arrival: float | None = None
        self._after_gap = False
        self.last_t_s: float | None = None

    @property
    def fs_hz(self) -> float:
        return self._envelope.rate() or self._fit.rate(self.nominal_rate_hz)

    @property
    def fs_rel_std(self) -> float | None:
        """The relative standard error of ``fs_hz``: None until the envelope gives the rate (the least-squares
        rate of the first seconds is only a start)."""
        return self._envelope.rate_rel_std()

    def begin(self, resume: bool) -> None:
        """Streaming (re)starts; ``resume``: after a reconnection, so the next arrival follows a gap."""
        self._after_gap = resume and self._last_arrival is not None

    def place(self, arrival_s: float, gyro: np.ndarray, accel: np.ndarray, saturated: np.ndarray) -> SampleBatch:
        """The batch of ``len(gyro)`` samples whose notification arrived at ``arrival_s``."""
        n = len(gyro)
        fs = self.fs_hz
        lost = 0
        if self._arrival0 is None:
            self._arrival0 = arrival_s - (n - 1) / fs
            self._t_next = 0.0
        elif self._after_gap and self._last_arrival is not None:
            sent = self._envelope.sent_at(self._counter - 1)
            before = self._last_arrival if sent is None else min(self._last_arrival, self._arrival0 + sent)
            lost = max(0, int(round((arrival_s - before) * fs)) - n)
        self._after_gap = False
        self._last_arrival = arrival_s
        assert self._t_next is not None
        t = self._t_next + (lost + np.arange(n)) / fs
        counter0 = self._counter + lost
        self._counter = counter0 + n
        self._fit.add(self._counter - 1, int(round((arrival_s - self._arrival0) * 1e6)))
        self._envelope.add(self._counter - 1, arrival_s - self._arrival0)
        fs = self.fs_hz
        self._t_next = float(t[-1]) + 1.0 / fs
        self.last_t_s = float(t[-1])
        st = self.stats
        st.packets += 1
        st.samples += n
        st.fs_estimate_hz = fs
        if lost:
            st.lost_samples += lost
            st.lost_packets += max(1, lost // n)
        return SampleBatch(t, gyro, accel, np.arange(counter0, counter0 + n, dtype=np.int64), lost, fs, saturated, True,
                           self.fs_rel_std)
