"""The physics of checking one hand turn as it is recorded: the angle it swept about each axis, whether
the device came to rest after a full turn and then moved on, and how far gravity moved across it.

Pure functions on arrays (time s, gyro deg/s, accelerometer g); the guided session applies them with its
tolerances (calib.judge.acceptance.Tolerances).
"""

from __future__ import annotations

import numpy as np


def swept_angles(t: np.ndarray, gyro: np.ndarray, bias: np.ndarray | float = 0.0) -> np.ndarray:
    """Integrated raw angle (deg) about x, y, z over a stretch (t (n,), gyro (n, 3)), the rest reading
    ``bias`` (deg/s) removed; zeros for fewer than 2 samples."""
    if t.size < 2:
        return np.zeros(3)
    return ((gyro[1:] - bias) * np.diff(t)[:, None]).sum(axis=0)


def rest_after_full_turn(t: np.ndarray, gyro: np.ndarray, bias: np.ndarray | float, axis: int, noise_floor: float | None,
                         rest_s: float, min_angle_deg: float) -> bool:
    """Whether a motion holds a rest of at least ``rest_s`` after sweeping ``min_angle_deg`` about ``axis`` and
    then moves again (two motions the stage detector merged: a full turn, a short rest, a bump)."""
    if t.size < 3:
        return False
    m = gyro - bias
    quiet = np.linalg.norm(m, axis=1) < max(1.0, 8.0 * (noise_floor or 0.0))
    angle = np.concatenate([[0.0], np.cumsum(m[1:, axis] * np.diff(t))])
    edges = np.flatnonzero(np.diff(np.concatenate([[0], quiet.astype(np.int8), [0]])))
    n = m.shape[0]
    for a, b in zip(edges[::2], edges[1::2], strict=True):  # quiet runs [a, b)
        long_enough = t[b - 1] - t[a] >= rest_s
        moves_after = b < n and bool(np.any(~quiet[b:]))
        if long_enough and moves_after and abs(angle[a]) >= min_angle_deg:
            return True
    return False


def angle_between_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (deg) between two vectors (e.g. two mean accelerometer readings: how far gravity moved)."""
    cos = float(np.dot(a, b) / max(float(np.linalg.norm(a) * np.linalg.norm(b)), 1e-12))
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def gravity_change_deg(accel_before: np.ndarray, accel_after: np.ndarray) -> float | None:
    """Angle (deg) between gravity in the rest before a turn and in the rest after it (0 when the device was
    put back in place); None when either rest is too short or not resting (|a| far from 1 g)."""
    if accel_before.shape[0] < 2 or accel_after.shape[0] < 2:
        return None
    a, b = accel_before.mean(axis=0), accel_after.mean(axis=0)
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if not (0.5 < na < 1.5 and 0.5 < nb < 1.5):
        return None
    return angle_between_deg(a, b)
