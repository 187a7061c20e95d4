"""Cramer-Rao bounds for the calibration protocol: how well any unbiased estimator can do.

The exact bound of a recording is the inverse Fisher information of the closure model at its
solution (calib.estimators.closure.estimator reports it as ``k_bound``/``b_bound``). ``protocol_bound`` is its closed form
for one axis of the paper's protocol, derived from the same model with the cross-axis terms left out:

    turn about axis i (duration T): closure  k (A - beta T) = 360 deg,  A = sum m_i dt,  var A = sigma^2 T / fs
    stills (total duration T_s):    beta = mean reading at rest = -b / k,  var beta = sigma^2 / (fs T_s)

so dk = -(k^2 / 360) (dA - T dbeta) and db = d(-k beta) = -beta dk - k dbeta, which give

    sigma_k = (k^2 sigma / 360) sqrt(T / fs) sqrt(1 + T / T_s)
    sigma_b^2 = (b k / 360)^2 sigma^2 T / fs + k^2 (1 - b T / 360)^2 sigma^2 / (fs T_s)

(sigma: reading noise std, deg/s; fs: sample rate, Hz; b in deg/s). For k = 1 and b = 0 these are
sigma (sqrt(T / fs) / 360) sqrt(1 + T / T_s) and sigma / sqrt(fs T_s).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from calib.units import FULL_TURN_DEG


def protocol_bound(
    noise_dps: ArrayLike,
    fs: float,
    turn_s: ArrayLike,
    still_s: float,
    k: ArrayLike = 1.0,
    b: ArrayLike = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form Cramer-Rao bound (sigma_k, sigma_b in deg/s) per axis for one turn per axis.

    noise_dps: reading noise std (deg/s), scalar or per axis; fs: sample rate (Hz); turn_s: duration
    of the turn about each axis (s); still_s: total time at rest (s); k, b: the sensor's parameters.
    """
    sigma = np.asarray(noise_dps, dtype=float)
    T = np.asarray(turn_s, dtype=float)
    k = np.asarray(k, dtype=float)
    b = np.asarray(b, dtype=float)
    if fs <= 0 or still_s <= 0 or np.any(T <= 0):
        raise ValueError("fs, turn_s and still_s must be positive")
    var_angle = sigma**2 * T / fs  # of the raw integrated turn angle, deg^2
    var_offset = sigma**2 / (fs * still_s)  # of the mean reading at rest, (deg/s)^2
    sigma_k = (k**2 / FULL_TURN_DEG) * np.sqrt(var_angle + T**2 * var_offset)
    sigma_b = np.sqrt((b * k / FULL_TURN_DEG) ** 2 * var_angle + k**2 * (1.0 - b * T / FULL_TURN_DEG) ** 2 * var_offset)
    return np.broadcast_to(sigma_k, np.broadcast(sigma_k, sigma_b).shape).copy(), np.broadcast_to(
        sigma_b, np.broadcast(sigma_k, sigma_b).shape
    ).copy()


