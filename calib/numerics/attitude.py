"""Attitude from angular rates: the running product of incremental rotations, vectorised."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from calib.numerics.quaternion import prefix_products


def cumulative_attitude(rates_dps: np.ndarray, dt: float | np.ndarray) -> Rotation:
    """Attitude C_t = Exp(g_0 dt) ... Exp(g_t dt) after each sample, as a stack of rotations.

    ``rates_dps`` (n, 3) in deg/s; ``dt`` scalar or (n,) s. C_t maps body vectors at sample t into the
    frame of the start. Computed by a blocked scan of quaternion products (calib.numerics.quaternion).
    """
    rotvec = np.deg2rad(np.asarray(rates_dps, dtype=float)) * np.reshape(dt, (-1, 1))
    q = Rotation.from_rotvec(rotvec).as_quat()
    return Rotation.from_quat(prefix_products(q.T).T)
