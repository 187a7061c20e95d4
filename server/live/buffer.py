"""Every sample a guided session received, in growing arrays (amortised O(1) appends)."""

from __future__ import annotations

import numpy as np

from calib.recording import Recording, RecordingMeta


class SampleBuffer:
    """Growing arrays of every sample a session received (amortised O(1) appends)."""

    def __init__(self, with_accel: bool = True) -> None:
        self.n = 0
        cap = 4096
        self.t = np.empty(cap)
        self.gyro = np.empty((cap, 3))
        self.accel = np.empty((cap, 3)) if with_accel else None
        self.seq = np.empty(cap, dtype=np.int64)
        self.has_seq = True
        self.has_accel = with_accel

    def _grow(self, need: int) -> None:
        cap = self.t.size
        if need <= cap:
            return
        while cap < need:
            cap *= 2
        self.t = np.resize(self.t, cap)
        self.gyro = np.resize(self.gyro, (cap, 3))
        if self.accel is not None:
            self.accel = np.resize(self.accel, (cap, 3))
        self.seq = np.resize(self.seq, cap)

    def append(self, t: np.ndarray, gyro: np.ndarray, accel: np.ndarray | None, seq: np.ndarray | None) -> tuple[int, int]:
        """Append one batch; returns its global index range [start, end)."""
        k = t.size
        start = self.n
        self._grow(start + k)
        self.t[start : start + k] = t
        self.gyro[start : start + k] = gyro
        if self.accel is not None:
            if accel is None:
                self.accel = None
                self.has_accel = False
            else:
                self.accel[start : start + k] = accel
        if seq is None:
            self.has_seq = False
        else:
            self.seq[start : start + k] = seq
        self.n += k
        return start, self.n

    def recording(self, meta: RecordingMeta) -> Recording:
        n = self.n
        return Recording(
            t=self.t[:n].copy(),
            gyro=self.gyro[:n].copy(),
            accel=None if self.accel is None or not self.has_accel else self.accel[:n].copy(),
            seq=self.seq[:n].copy() if self.has_seq else None,
            meta=meta,
        )
