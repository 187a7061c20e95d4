"""The tilt a motion leaves the device in, from gravity at the rests on either side of it.

At rest the accelerometer reads gravity in the device's frame. If the pose after a motion is the pose before rotated
by a small rho (body frame), gravity before and after, as unit vectors, satisfy u0 = u1 + rho x u1: the component of
rho perpendicular to gravity (the tilt) is u x (u0 - u1), u the mean direction. The component about gravity (a turn
on the table, the heading) leaves gravity unchanged and cannot be measured this way. An accelerometer's bias cancels
in u0 - u1; its scale errors scale the tilt by under 1 part in 100.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.units import DEG


@dataclass(frozen=True)
class TiltAcross:
    """The tilt across motions (any leading shape ``...``)."""

    rho_deg: np.ndarray  # (..., 3) the rotation from the pose before to the pose after, perpendicular to gravity, deg
    up: np.ndarray  # (..., 3) unit gravity direction (body frame), the mean of before and after
    sd_deg: np.ndarray  # (...,) standard deviation of each tilt component, deg


def tilt_across(a0: np.ndarray, a1: np.ndarray, n0: np.ndarray | float, n1: np.ndarray | float,
                sigma_g: np.ndarray | float) -> TiltAcross:
    """The tilt from the mean specific force before (``a0``, (..., 3), g, of ``n0`` samples) and after (``a1``, of
    ``n1``), with the accelerometer's noise ``sigma_g`` (g per sample and axis)."""
    a0 = np.asarray(a0, dtype=float)
    a1 = np.asarray(a1, dtype=float)
    g0 = np.linalg.norm(a0, axis=-1, keepdims=True)
    g1 = np.linalg.norm(a1, axis=-1, keepdims=True)
    u0, u1 = a0 / g0, a1 / g1
    u = u0 + u1
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    rho = np.cross(u, u0 - u1) / DEG
    g = 0.5 * (g0 + g1)[..., 0]
    sd = np.asarray(sigma_g) * np.sqrt(1.0 / np.asarray(n0, dtype=float) + 1.0 / np.asarray(n1, dtype=float)) / g / DEG
    return TiltAcross(rho, u, sd)
