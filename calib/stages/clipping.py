"""The stage detector's clipping test, carried across batches: readings that sit at the largest magnitude seen so far
for longer than chance repeats of a count allow (the gyro's range reached), or beyond a stated full scale."""

from __future__ import annotations

import numpy as np

from calib.stages.config import StageConfig, clip_run_needed


class ClipTracker:
    """Which readings of each batch are clipped; ``saturated`` takes the batches in order, any sizes."""

    def __init__(self, config: StageConfig, full_scale_dps: float | None) -> None:
        self.config = config
        self.full_scale_dps = full_scale_dps
        self._max = np.zeros(3)  # the largest |reading| so far, per axis
        self._run = np.zeros(3, dtype=np.int64)  # length of the run of identical readings ending at the last one
        self._equal_pairs = np.zeros(3, dtype=np.int64)  # consecutive readings so far that are equal, per axis
        self._last: np.ndarray | None = None
        self._seen = 0

    def saturated(self, x: np.ndarray) -> np.ndarray:
        """For the next readings x (k, 3) deg/s: (k,) True where a reading is clipped."""
        cfg = self.config
        k = x.shape[0]
        if self.full_scale_dps is not None:
            self._seen += k
            return np.any(np.abs(x) >= cfg.full_scale_fraction * self.full_scale_dps, axis=1)
        xt = np.ascontiguousarray(x.T)  # axis-major: each pass below runs along one axis' readings
        a = np.abs(xt)
        same = np.empty((3, k), dtype=bool)
        same[:, 0] = xt[:, 0] == self._last if self._last is not None else False
        np.equal(xt[:, 1:], xt[:, :-1], out=same[:, 1:])
        out = np.zeros(k, dtype=bool)
        for axis in range(3):
            equal_at = np.flatnonzero(same[axis])  # readings equal to the one before
            # only a reading at the running maximum (and above clip_min_dps) can be a clipped one, and every reading
            # of its run of identical ones is as large: the runs are found among the large readings alone
            big = np.flatnonzero(a[axis] >= cfg.clip_min_dps)
            if big.size:
                value = a[axis, big]
                top = value >= np.maximum(np.maximum.accumulate(value), self._max[axis])
                # a large reading continues a run when it is the next sample and equal to the one before
                goes_on = same[axis, big]
                goes_on[1:] &= np.diff(big) == 1
                run_start = np.maximum.accumulate(np.where(goes_on, 0, np.arange(big.size)))
                rows, first = big[top], run_start[top]
                carried = goes_on[first]  # a run that began in an earlier batch (only the first large reading's)
                run_len = rows - big[first] + 1 + np.where(carried, self._run[axis], 0)
                long = run_len >= cfg.clip_run  # no shorter run is ever enough
                if long.any():
                    rows, run_len = rows[long], run_len[long]
                    equal = self._equal_pairs[axis] + np.searchsorted(equal_at, rows, side="right")
                    pairs = np.maximum(self._seen + rows, 1)
                    out[rows[run_len >= clip_run_needed(equal / pairs, cfg.clip_run, cfg.clip_chance)]] = True
                self._max[axis] = max(self._max[axis], float(value.max()))
            self._run[axis] = _trailing_run(equal_at, k, int(self._run[axis]))
            self._equal_pairs[axis] += equal_at.size
        self._last = x[-1].copy()
        self._seen += k
        return out


def _trailing_run(equal_at: np.ndarray, k: int, run_before: int) -> int:
    """The length of the run of identical readings ending at the last of k readings, from the sorted indices
    ``equal_at`` of those equal to the reading before (the first to the previous batch's last, whose run was
    ``run_before``)."""
    tail = equal_at.size
    if tail and equal_at[-1] == k - 1:
        breaks = np.flatnonzero(equal_at != np.arange(k - tail, k))
        tail -= int(breaks[-1]) + 1 if breaks.size else 0
    else:
        tail = 0
    return run_before + k if tail == k else tail + 1
