"""The detector's sample store: recent samples and their running (prefix) sums, addressed by global sample index."""

from __future__ import annotations

import numpy as np

# Columns of the running (prefix) sums kept per sample, relative to the first reading x0.
S1 = slice(0, 3)  # x - x0
S2 = slice(3, 6)  # (x - x0)^2
DT = 6  # dt_i = t_i - t_{i-1}
MDT = slice(7, 10)  # (x - x0) dt
TDT = 10  # (t - t0) dt
SAT = 11  # saturated samples
GAP = 12  # counter jumps
NCOL = 13


def spread(sums: np.ndarray, count: int) -> np.ndarray:
    """The readings' spread about their mean (deg/s, rms over the axes) from the running sums (..., NCOL) over
    ``count`` samples."""
    var = np.maximum(sums[..., S2] / count - (sums[..., S1] / count) ** 2, 0.0)
    return np.sqrt(var.mean(axis=-1))


class PrefixStore:
    """Recent samples and their running sums, addressed by global sample index."""

    def __init__(self, cap: int) -> None:
        self.base = 0  # global index of row 0
        self.n = 0  # samples received
        self.x = np.empty((cap, 3))
        self.t = np.empty(cap)
        self.p = np.zeros((cap + 1, NCOL))  # p[r] = sums over samples before global index base + r

    def append(self, x: np.ndarray, t: np.ndarray, values: np.ndarray, keep_from: int) -> None:
        """Add k samples (x (k, 3), t (k,)) with their per-sample ``values`` (k, NCOL), which are used up; rows
        before ``keep_from`` may be dropped to make room."""
        k = t.size
        used = self.n - self.base
        if used + k > self.t.size:
            keep_from = min(max(keep_from, self.base), self.n)
            drop = keep_from - self.base
            if drop > 0:
                kept = used - drop
                self.x[:kept] = self.x[drop:used]
                self.t[:kept] = self.t[drop:used]
                self.p[: kept + 1] = self.p[drop : used + 1]
                self.base, used = keep_from, kept
            if used + k > self.t.size:
                cap = max(2 * self.t.size, used + k)
                self.x = np.concatenate([self.x[:used], np.empty((cap - used, 3))])
                self.t = np.concatenate([self.t[:used], np.empty(cap - used)])
                self.p = np.concatenate([self.p[: used + 1], np.zeros((cap - used, NCOL))])
        self.x[used : used + k] = x
        self.t[used : used + k] = t
        # Running sums carry over exactly (cumsum adds in sample order), so any batching gives the same bits.
        values[0] += self.p[used]  # the sum so far, added first: the same additions in the same order
        np.cumsum(values, axis=0, out=self.p[used + 1 : used + k + 1])
        self.n += k

    def _local(self, i: int) -> int:
        if i < self.base:
            raise AssertionError(f"sample {i} is no longer kept (oldest kept: {self.base})")
        return i - self.base

    def row(self, i: int) -> np.ndarray:
        return self.p[self._local(i)]

    def sums(self, a: int, b: int) -> np.ndarray:
        return self.p[self._local(b)] - self.p[self._local(a)]

    def time(self, i: int) -> float:
        return float(self.t[self._local(i)])
