"""The ranges the simulator draws a sensor and a hand from (the paper's Section 4), and its fixed constants."""

from __future__ import annotations

import numpy as np

# Paper Section 3 distributions and the protocol of Section 2.3.
K_RANGE = (0.8, 1.2)  # scale factor, dimensionless
B_RANGE_DPS = (-5.0, 5.0)  # bias, deg/s of true rate
TILT_RANGE = 0.1  # off-axis component of a turn's true axis, U(-0.1, 0.1) each
TURN_DURATION_S = (2.5, 5.0)  # hand turn duration, uniform
WOBBLE_DEG = (0.5, 3.0)  # hand wobble amplitude, uniform
STILL_S = 3.0  # rest before, between and after the turns
ACCEL_NOISE_G = 0.002
GRAVITY_UP = np.array([0.0, 0.0, 1.0])  # specific force at rest, start frame, g
_BEZIER_DEGREE = 6  # control points 0, 0, p1, p2, p3, 1, 1: zero rate at both ends
N_PROFILE = _BEZIER_DEGREE - 3
WOBBLE_HARMONIC_SCALE = np.array([1.0, 0.5])  # amplitude of sin(pi s), sin(2 pi s)
