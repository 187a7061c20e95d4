"""Attitude from angular rates: the running product of incremental rotations, vectorised."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def _qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of scalar-last quaternions, broadcast over leading axes."""
    px, py, pz, pw = np.moveaxis(p, -1, 0)
    qx, qy, qz, qw = np.moveaxis(q, -1, 0)
    return np.stack(
        (
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
            pw * qw - px * qx - py * qy - pz * qz,
        ),
        axis=-1,
    )


def cumulative_attitude(rates_dps: np.ndarray, dt: float | np.ndarray) -> Rotation:
    """Attitude C_t = Exp(g_0 dt) ... Exp(g_t dt) after each sample, as a stack of rotations.

    ``rates_dps`` (n, 3) in deg/s; ``dt`` scalar or (n,) s. C_t maps body vectors at sample t into the
    frame of the start. Computed by a parallel prefix (Hillis-Steele) scan of quaternion products:
    log2(n) vectorised steps instead of n sequential ones.
    """
    rotvec = np.deg2rad(np.asarray(rates_dps, dtype=float)) * np.reshape(dt, (-1, 1))
    q = Rotation.from_rotvec(rotvec).as_quat()
    shift = 1
    while shift < len(q):
        q[shift:] = _qmul(q[:-shift], q[shift:])
        shift *= 2
    return Rotation.from_quat(q)
