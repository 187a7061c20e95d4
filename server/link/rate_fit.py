"""The running least-squares estimate of a stream's true sample rate from (sample counter, time) pairs."""

from __future__ import annotations

MIN_SPAN_FOR_RATE_S = 0.5  # below this span of time the nominal rate is used


class RateFit:
    """Running least-squares fit t = a + counter / fs over (counter, t_us) pairs, centred for accuracy."""

    def __init__(self) -> None:
        self.n = 0
        self.x0 = 0
        self.y0 = 0
        self.sx = self.sy = self.sxx = self.sxy = 0.0
        self.span_us = 0

    def add(self, counter: int, t_us: int) -> None:
        if self.n == 0:
            self.x0, self.y0 = counter, t_us
        x = float(counter - self.x0)
        y = float(t_us - self.y0)
        self.n += 1
        self.sx += x
        self.sy += y
        self.sxx += x * x
        self.sxy += x * y
        self.span_us = max(self.span_us, t_us - self.y0)

    def rate(self, nominal: float) -> float:
        if self.n < 3 or self.span_us < MIN_SPAN_FOR_RATE_S * 1e6:
            return nominal
        var = self.sxx - self.sx * self.sx / self.n
        cov = self.sxy - self.sx * self.sy / self.n
        if var <= 0 or cov <= 0:
            return nominal
        return 1e6 * var / cov
