"""Sample times for devices that send none: from the central's arrival times, flagged as such.

A notification's arrival time jitters by the connection interval, so single arrival times are not used as
sample times: the true rate is the least-squares slope of sample count against arrival time over the
session (the nominal rate until 0.5 s is in) and samples are spaced by it. Without a counter, lost
samples cannot be detected while the link holds; after a reconnection the gap is estimated from the
arrival times (rounded to whole samples) and reported like any other loss.
"""

from __future__ import annotations

import numpy as np

from ..base import LinkStats, SampleBatch
from .base import RateFit


class ArrivalTimeline:
    """Places the samples of each notification on a time line from arrival times."""

    def __init__(self, stats: LinkStats, nominal_rate_hz: float) -> None:
        self.stats = stats
        self.nominal_rate_hz = nominal_rate_hz
        self._fit = RateFit()
        self._counter = 0
        self._t_next: float | None = None  # time (s from the first sample) of the next sample
        self._arrival0: float | None = None
        self._last_arrival: float | None = None
        self._after_gap = False
        self.last_t_s: float | None = None

    @property
    def fs_hz(self) -> float:
        return self._fit.rate(self.nominal_rate_hz)

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
            lost = max(0, int(round((arrival_s - self._last_arrival) * fs)) - n)
        self._after_gap = False
        self._last_arrival = arrival_s
        assert self._t_next is not None
        t = self._t_next + (lost + np.arange(n)) / fs
        counter0 = self._counter + lost
        self._counter = counter0 + n
        self._fit.add(self._counter - 1, int(round((arrival_s - self._arrival0) * 1e6)))
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
        return SampleBatch(t, gyro, accel, np.arange(counter0, counter0 + n, dtype=np.int64), lost, fs, saturated, True)
