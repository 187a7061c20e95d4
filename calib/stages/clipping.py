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
        a = np.abs(x)
        cfg = self.config
        k = x.shape[0]
        if self.full_scale_dps is not None:
            self._seen += k
            return np.any(a >= cfg.full_scale_fraction * self.full_scale_dps, axis=1)
        run_max = np.maximum(np.maximum.accumulate(a, axis=0), self._max)
        same = np.empty((k, 3), dtype=bool)
        same[0] = x[0] == self._last if self._last is not None else False
        same[1:] = x[1:] == x[:-1]
        # only a reading at the running maximum (and above clip_min_dps) can be a clipped one: its run's length and
        # the run it needs are found for those alone, from where each axis' readings last changed
        candidate = (a >= cfg.clip_min_dps) & (a >= run_max)
        out = np.zeros(k, dtype=bool)
        for axis in range(3):
            changes = np.flatnonzero(~same[:, axis])  # readings that differ from the one before
            rows = np.flatnonzero(candidate[:, axis])
            if rows.size:
                before = np.searchsorted(changes, rows, side="right") - 1  # the last change at or before each row
                last = changes[np.maximum(before, 0)] if changes.size else rows
                run_len = np.where(before >= 0, rows - last + 1, self._run[axis] + rows + 1)
                equal = self._equal_pairs[axis] + rows - before  # equal neighbours so far, the row's own included
                pairs = np.maximum(self._seen + rows, 1)
                out[rows[run_len >= clip_run_needed(equal / pairs, cfg.clip_run, cfg.clip_chance)]] = True
            self._run[axis] = k - changes[-1] if changes.size else self._run[axis] + k
            self._equal_pairs[axis] += k - changes.size
        self._max = run_max[-1].copy()
        self._last = x[-1].copy()
        self._seen += k
        return out
