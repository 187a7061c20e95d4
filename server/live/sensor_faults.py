"""Readings no working sensor gives while it rests, named as the sensor's fault rather than the clinician's hands.

Checked only while the session asks the device to rest (the initial rest, the pauses), over the last
WINDOW_S of the session's samples, read from its buffer (a window of its own, copied at every batch, cost a busy
service more than the checks):

- a gyroscope axis that reads exactly the same value, beyond STUCK_MIN_DPS, for the whole window: a real
  sensor's noise moves it by a count or more; a hand cannot hold a turn rate that still;
- a gyroscope axis at its full-scale limit for the whole window (a hand resting the device cannot);
- an accelerometer whose magnitude, with the gyroscope quiet, is outside GRAVITY_RANGE_G: at rest it reads
  gravity, 1 g, whichever way up the device lies.
"""

from __future__ import annotations

import numpy as np

from .buffer import SampleBuffer

WINDOW_S = 1.0
CHECK_EVERY_S = 0.1  # of device time: a fault holds a whole window, so it is named at most this much later
STUCK_MIN_DPS = 5.0  # a constant reading below this could be a quiet sensor's bias; above it, a stuck axis
RAIL_FRACTION = 0.98  # of the full scale: the reading is at the sensor's limit
QUIET_DPS = 3.0  # every gyroscope axis below this: the device rests, and the accelerometer reads gravity alone
GRAVITY_RANGE_G = (0.7, 1.3)
AXES = "XYZ"


class SensorFaultWatch:
    """Reads the last WINDOW_S of a session's samples (its buffer) at most every CHECK_EVERY_S of device time;
    ``check`` says what is wrong with the sensor, or None."""

    def __init__(self) -> None:
        self._checked_at = -np.inf

    def check(self, buf: SampleBuffer, full_scale_dps: float | None) -> str | None:
        """The sensor's fault in the clinician's words, when the buffer's last window shows one."""
        n = buf.n
        if n == 0 or buf.t[n - 1] - self._checked_at < CHECK_EVERY_S:
            return None
        self._checked_at = float(buf.t[n - 1])
        lo = int(np.searchsorted(buf.t[:n], buf.t[n - 1] - WINDOW_S))
        accel = buf.accel[lo:n] if buf.accel is not None and buf.has_accel else None
        return fault_in(buf.t[lo:n], buf.gyro[lo:n], accel, full_scale_dps)


def fault_in(t: np.ndarray, g: np.ndarray, a: np.ndarray | None, full_scale_dps: float | None) -> str | None:
    """What is wrong with the sensor whose readings at rest over a window are ``g`` (deg/s) and ``a`` (g), or None."""
    if len(t) < 10 or t[-1] - t[0] < 0.95 * WINDOW_S:
        return None
    for i, axis in enumerate(AXES):
        col = g[:, i]
        if full_scale_dps and np.all(np.abs(col) >= RAIL_FRACTION * full_scale_dps):
            return (f"The gyroscope's {axis} axis stays at its limit ({col[-1]:+.0f} deg/s of ±{full_scale_dps:.0f}) "
                    "while the device rests: the sensor is faulty.")
        if np.ptp(col) == 0 and abs(col[0]) > STUCK_MIN_DPS:
            return (f"The gyroscope's {axis} axis reads exactly {col[0]:+.1f} deg/s, unchanging, while the device "
                    "rests: it is stuck and the sensor is faulty.")
    if a is not None and np.all(np.isfinite(a)) and np.all(np.abs(g) < QUIET_DPS):
        magnitude = float(np.linalg.norm(a, axis=1).mean())
        low, high = GRAVITY_RANGE_G
        if not low <= magnitude <= high:
            return (f"The accelerometer reads {magnitude:.2f} g while the device rests, where gravity gives 1 g "
                    "whichever way up it lies: the accelerometer is faulty or misconfigured.")
    return None

