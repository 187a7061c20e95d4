"""The detector's sample store: recent sample times and the running (prefix) sums, addressed by global sample index."""

from __future__ import annotations

import numpy as np

# Rows of the running (prefix) sums kept per sample, relative to the first reading x0.
S1 = slice(0, 3)  # x - x0
S2 = slice(3, 6)  # (x - x0)^2
DT = 6  # dt_i = t_i - t_{i-1}
MDT = slice(7, 10)  # (x - x0) dt
TDT = 10  # (t - t0) dt
NCOL = 11


def spread(sums: np.ndarray, count: int) -> np.ndarray:
    """The readings' spread about their mean (deg/s, rms over the axes) from the running sums (NCOL, ...) over
    ``count`` samples."""
    var = np.maximum(sums[S2] / count - (sums[S1] / count) ** 2, 0.0)
    return np.sqrt(var.mean(axis=0))


class PrefixStore:
    """Recent sample times and the running sums, addressed by global sample index.

    The sums are kept axis-major, ``p`` (NCOL, rows): every pass over the samples then runs along contiguous rows
    (arrays of (samples, 3) spend most of a pass stepping across their three-wide rows)."""

    def __init__(self, cap: int) -> None:
        self.base = 0  # global index of row 0
        self.n = 0  # samples received
        self.t = np.empty(cap)
        self.p = np.zeros((NCOL, cap + 1))  # p[:, r] = sums over samples before global index base + r

    def append(self, t: np.ndarray, values: np.ndarray, keep_from: int) -> None:
        """Add k samples at times t (k,) with their per-sample ``values`` (NCOL, k), which are used up; samples before
        ``keep_from`` may be dropped to make room."""
        k = t.size
        used = self.n - self.base
        if used + k > self.t.size:
            keep_from = min(max(keep_from, self.base), self.n)
            drop = keep_from - self.base
            if drop > 0:
                kept = used - drop
                self.t[:kept] = self.t[drop:used]
                self.p[:, : kept + 1] = self.p[:, drop : used + 1]
                self.base, used = keep_from, kept
            if used + k > self.t.size:
                cap = max(2 * self.t.size, used + k)
                t_old, p_old = self.t, self.p
                self.t, self.p = np.empty(cap), np.empty((NCOL, cap + 1))  # rows past n are written before they are read
                self.t[:used] = t_old[:used]
                self.p[:, : used + 1] = p_old[:, : used + 1]
        self.t[used : used + k] = t
        # Running sums carry over exactly (cumsum adds in sample order), so any batching gives the same bits.
        values[:, 0] += self.p[:, used]  # the sum so far, added first: the same additions in the same order
        np.cumsum(values, axis=1, out=self.p[:, used + 1 : used + k + 1])
        self.n += k

    def _local(self, i: int) -> int:
        if i < self.base:
            raise AssertionError(f"sample {i} is no longer kept (oldest kept: {self.base})")
        return i - self.base

    def row(self, i: int) -> np.ndarray:
        """The running sums before sample i (NCOL,), a copy."""
        return self.p[:, self._local(i)].copy()

    def sums(self, a: int, b: int) -> np.ndarray:
        """The sums over samples [a, b) (NCOL,)."""
        return self.p[:, self._local(b)] - self.p[:, self._local(a)]

    def time(self, i: int) -> float:
        return float(self.t[self._local(i)])
