"""Readings no working sensor gives while it rests, named as the sensor's fault rather than the clinician's hands.

Checked only while the session asks the device to rest (the initial rest, the pauses), over the last
WINDOW_S of samples:

- a gyroscope axis that reads exactly the same value, beyond STUCK_MIN_DPS, for the whole window: a real
  sensor's noise moves it by a count or more; a hand cannot hold a turn rate that still;
- a gyroscope axis at its full-scale limit for the whole window (a hand resting the device cannot);
- an accelerometer whose magnitude, with the gyroscope quiet, is outside GRAVITY_RANGE_G: at rest it reads
  gravity, 1 g, whichever way up the device lies.
"""

from __future__ import annotations

import numpy as np

WINDOW_S = 1.0
STUCK_MIN_DPS = 5.0  # a constant reading below this could be a quiet sensor's bias; above it, a stuck axis
RAIL_FRACTION = 0.98  # of the full scale: the reading is at the sensor's limit
QUIET_DPS = 3.0  # every gyroscope axis below this: the device rests, and the accelerometer reads gravity alone
GRAVITY_RANGE_G = (0.7, 1.3)
AXES = "XYZ"


class SensorFaultWatch:
    """Keeps the last WINDOW_S of samples; ``check`` says what is wrong with the sensor, or None."""

    def __init__(self) -> None:
        self._t = np.empty(0)
        self._gyro = np.empty((0, 3))
        self._accel: np.ndarray | None = None

    def add(self, t: np.ndarray, gyro: np.ndarray, accel: np.ndarray | None) -> None:
        self._t = np.concatenate([self._t, t])
        self._gyro = np.concatenate([self._gyro, gyro])
        if accel is not None and (self._accel is None or len(self._accel) == len(self._t) - len(t)):
            self._accel = accel if self._accel is None else np.concatenate([self._accel, accel])
        else:
            self._accel = None  # an accelerometer that comes and goes is not judged
        keep = self._t >= self._t[-1] - WINDOW_S
        self._t, self._gyro = self._t[keep], self._gyro[keep]
        if self._accel is not None:
            self._accel = self._accel[keep]

    def reset(self) -> None:
        self.__init__()  # type: ignore[misc]

    def check(self, full_scale_dps: float | None) -> str | None:
        """The sensor's fault in the clinician's words, when the window shows one."""
        if len(self._t) < 10 or self._t[-1] - self._t[0] < 0.95 * WINDOW_S:
            return None
        g = self._gyro
        for i, axis in enumerate(AXES):
            col = g[:, i]
            if full_scale_dps and np.all(np.abs(col) >= RAIL_FRACTION * full_scale_dps):
                return (f"The gyroscope's {axis} axis stays at its limit ({col[-1]:+.0f} deg/s of ±{full_scale_dps:.0f}) "
                        "while the device rests: the sensor is faulty.")
            if np.ptp(col) == 0 and abs(col[0]) > STUCK_MIN_DPS:
                return (f"The gyroscope's {axis} axis reads exactly {col[0]:+.1f} deg/s, unchanging, while the device "
                        "rests: it is stuck and the sensor is faulty.")
        a = self._accel
        if a is not None and np.all(np.isfinite(a)) and np.all(np.abs(g) < QUIET_DPS):
            magnitude = float(np.linalg.norm(a, axis=1).mean())
            low, high = GRAVITY_RANGE_G
            if not low <= magnitude <= high:
                return (f"The accelerometer reads {magnitude:.2f} g while the device rests, where gravity gives 1 g "
                        "whichever way up it lies: the accelerometer is faulty or misconfigured.")
        return None

