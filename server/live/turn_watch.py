"""The turn in progress as the clinician should see it: its angle, and the moment its motion stops.

The stage detector decides "moving" and "still" on a centred window, so it learns that a hand turn has
ended 0.25-0.35 s late; the page must say "hold it still" as soon as the device stops, so the stop is read
here from the last ``STOP_WINDOW_S`` of readings against the rest reading.

The live angle is the detector's bias-compensated integral of the raw readings. With the device's accepted
calibration K (eq. 1, g = K m + b; the bias cancels against the rest reading) it becomes K times that: a
true angle, with a full turn as its target. Without one the raw angle can be 20 % off a full turn
(k = 0.8-1.2), so it has no target and the turn is done when the device rests back in its place.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.units import FULL_TURN_DEG

STOP_WINDOW_S = 0.06  # the readings that decide "stopped": the last 60 ms
STOP_DPS = 5.0  # stopped: every reading of that window within this rate of the rest reading (deg/s)
RESUME_DPS = 12.0  # turning again: a reading this far from rest (hysteresis against a hand's tremor)
NEAR_FULL_DEG = 40.0  # with a calibrated angle, a stop at least this close to a full turn means "put it down"
EARLY_TURN_DEG = 45.0  # a motion in a pause becomes the next turn once it has turned this far


@dataclass(frozen=True)
class LiveAngle:
    """How a session turns the detector's raw live angle into the angle it shows.

    ``scale`` is the 3x3 K of the device's accepted calibration, None when it has none. ``checks_turns``: the
    calibration was made on this device by a guided session, so its angle may also refuse a turn that is not a
    full one (an uploaded recording's calibration only drives the gauge).
    """

    scale: np.ndarray | None = None
    checks_turns: bool = True

    @classmethod
    def from_calibration(cls, k: list[float] | None, full_k: list[list[float]] | None = None, checks_turns: bool = True) -> LiveAngle:
        """From an accepted calibration's k (3,) or full K (3, 3); no calibration: the raw angle."""
        if full_k is not None:
            m = np.asarray(full_k, dtype=float)
        elif k is not None:
            m = np.diag(np.asarray(k, dtype=float))
        else:
            return cls(None)
        ok = m.shape == (3, 3) and bool(np.all(np.isfinite(m))) and bool(np.all(np.diag(m) > 0))
        return cls(m if ok else None, checks_turns)

    @property
    def calibrated(self) -> bool:
        return self.scale is not None

    @property
    def target_deg(self) -> float | None:
        """The angle a full turn reads: 360 deg when calibrated, None (unknown) on raw readings."""
        return FULL_TURN_DEG if self.scale is not None else None

    def of(self, raw_deg: np.ndarray) -> np.ndarray:
        """The shown angle (deg, about x, y, z) for a raw bias-compensated angle."""
        return raw_deg if self.scale is None else self.scale @ raw_deg

    def near_full(self, shown_deg: float) -> bool:
        """Whether a turn stopped at ``shown_deg`` may be a full one (always, when the angle is raw)."""
        return self.scale is None or abs(shown_deg) >= FULL_TURN_DEG - NEAR_FULL_DEG


def recent_rate_dps(gyro: np.ndarray, rest: np.ndarray | float, n: int) -> float:
    """The largest rate (deg/s, norm over the axes) among the last ``n`` readings, the rest reading removed."""
    if gyro.shape[0] == 0:
        return float("inf")
    tail = gyro[-max(1, n):] - rest
    return float(np.sqrt((tail * tail).sum(axis=1)).max())
