"""The units and the one constant of the method, stated once: angles are in degrees everywhere a user sees them
(radians only inside the geometry), a full turn sweeps 360 degrees, and the accelerometer reads in g (standard gravity, 9.80665 m/s^2)."""

from __future__ import annotations

import numpy as np

DEG = np.pi / 180.0  # radians per degree
FULL_TURN_DEG = 360.0  # the known angle of one full turn: what the calibration rests on
STANDARD_GRAVITY = 9.80665  # m/s^2 per g: accelerometers in m/s^2 are read into g with it
