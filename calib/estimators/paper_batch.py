"""The paper's Algorithm 1 on many simulated recordings at once (the Monte Carlo study), vectorised across runs:
the same steps as ``calib.estimators.paper.algorithm1``, with quaternion products instead of rotation objects."""

from __future__ import annotations

from typing import Any

import numpy as np

from calib.errors import RecordingError
from calib.estimators.paper import MAX_ITER, TOL, solve_scale_factors
from calib.numerics.quaternion import prefix_products
from calib.units import DEG, FULL_TURN_DEG


def rotvec_to_quat(phi: np.ndarray) -> np.ndarray:
    """Rodrigues' rotation (eq. 4) of the rotation vectors phi (3, ...) rad, as quaternions (4, ...).

    This is eq. 4 in quaternion form, vectorised over runs and samples; the batch path uses it
    instead of scipy's Rotation objects because the prefix product below needs plain arrays.
    """
    theta = np.sqrt(np.einsum("i...,i...->...", phi, phi))
    small = theta < 1e-6
    safe = np.where(small, 1.0, theta)
    half_sinc = np.where(small, 0.5 - theta * theta / 48.0, np.sin(0.5 * safe) / safe)  # sin(theta/2)/theta
    return np.concatenate((phi * half_sinc, np.cos(0.5 * theta)[None]), axis=0)


def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (3, 3, ...) of unit quaternions (4, ...) stored (x, y, z, w)."""
    x, y, z, w = q
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    return np.array(
        [
            [1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)],
            [2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)],
            [2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)],
        ]
    )


def _turn_means_batch(m_win: np.ndarray, dt: float, n: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Eq. (4)-(10) for turns stacked as sequences: A (N, 3, 3) = mean over the turn of C~_t.

    m_win: (3, L, N) bias-compensated readings of each turn, zero past the turn's end (zero rates
    are identity rotations, so padding changes nothing); n: (N,) samples in each turn; k: (N, 3).
    """
    q = rotvec_to_quat(m_win * (k.T[:, None, :] * dt * DEG))
    C = _quat_to_matrix(prefix_products(q))  # (3, 3, L, N)
    return np.einsum("icln,cln->nic", C, m_win) / n[:, None, None]


def _check_batch(gyro: np.ndarray, still0: np.ndarray, turns: np.ndarray) -> None:
    if gyro.ndim != 3 or gyro.shape[2] != 3:
        raise RecordingError(f"gyro must have shape (runs, samples, 3), got {gyro.shape}")
    R, n = gyro.shape[:2]
    if still0.shape != (R, 2) or turns.shape != (R, 3, 2):
        raise RecordingError(
            f"still0 must have shape ({R}, 2) and turns ({R}, 3, 2) for {R} runs; got {still0.shape} and {turns.shape}"
        )
    for name, b in (("still0", still0), ("turns", turns)):
        if np.any(b[..., 0] < 0) or np.any(b[..., 1] > n) or np.any(b[..., 1] <= b[..., 0]):
            raise RecordingError(f"{name} bounds must satisfy 0 <= start < end <= {n} (sample indices, end exclusive)")
    if not np.all(np.isfinite(gyro)):
        raise RecordingError("gyro readings contain NaN or infinite values: remove or repair those samples")


def algorithm1_batch(
    gyro: np.ndarray,
    dt: float,
    still0: np.ndarray,
    turns: np.ndarray,
    tol: float = TOL,
    max_iter: int = MAX_ITER,
    chunk: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Algorithm 1 on many recordings sampled at the same interval dt (s).

    gyro: (R, n, 3) raw readings m (deg/s); still0: (R, 2) sample bounds [start, end) of the first
    still; turns: (R, 3, 2) bounds of the x, y, z turns (each run may have its own bounds).
    Returns k (R, 3), b (R, 3) deg/s (eq. 1) and the number of scale-factor solves per run (R,);
    runs that did not converge within max_iter have iters == max_iter + 1, runs whose equations
    could not be solved get NaN parameters.
    """
    gyro = np.asarray(gyro, dtype=float)
    still0 = np.asarray(still0, dtype=np.int64)
    turns = np.asarray(turns, dtype=np.int64)
    _check_batch(gyro, still0, turns)
    if not dt > 0:
        raise RecordingError(f"dt must be a positive sample interval in seconds, got {dt}")
    R = gyro.shape[0]
    lengths = turns[..., 1] - turns[..., 0]
    L = int(lengths.max()) if R else 1
    if chunk is None:
        chunk = max(1, int(1e5 // (3 * L)))  # ~1e5 samples per pass stay in cache: measured fastest
    k = np.full((R, 3), np.nan)
    b = np.full((R, 3), np.nan)
    iters = np.zeros(R, dtype=np.int64)
    for lo in range(0, R, chunk):
        sl = slice(lo, min(R, lo + chunk))
        k[sl], b[sl], iters[sl] = _algorithm1_chunk(gyro[sl], dt, still0[sl], turns[sl], tol, max_iter)
    return k, b, iters


def _algorithm1_chunk(gyro, dt, still0, turns, tol, max_iter):
    R, n, _ = gyro.shape
    # step 1 (eq. 2): the mean reading over S0, per run
    rows = np.arange(R)
    n0 = still0[:, 1] - still0[:, 0]
    offs0 = np.arange(int(n0.max()))
    inside0 = offs0 < n0[:, None]
    still = gyro[rows[:, None], np.minimum(still0[:, 0, None] + offs0, n - 1)] * inside0[..., None]
    mean0 = still.sum(axis=1) / n0[:, None]

    # turn windows, stacked as 3R sequences of length L (turn j of run r is sequence j*R + r)
    lengths = turns[..., 1] - turns[..., 0]  # (R, 3)
    L = int(lengths.max())
    offs = np.arange(L)
    m_win = np.empty((3, L, 3 * R))
    for j in range(3):
        idx = np.minimum(turns[:, j, 0, None] + offs, n - 1)  # (R, L)
        inside = offs < lengths[:, j, None]
        win = (gyro[rows[:, None], idx] - mean0[:, None, :]) * inside[..., None]  # (R, L, 3)
        m_win[:, :, j * R : (j + 1) * R] = win.transpose(2, 1, 0)
    n_seq = lengths.T.reshape(-1).astype(float)  # (3R,)
    rate2 = (FULL_TURN_DEG / (lengths * dt)) ** 2  # (R, 3): (theta_total / T_j)^2

    k = np.ones((R, 3))
    iters = np.zeros(R, dtype=np.int64)
    active = np.arange(R)
    for it in range(1, max_iter + 1):
        seq = np.concatenate([active + j * R for j in range(3)])
        A = _turn_means_batch(m_win[:, :, seq], dt, n_seq[seq], np.tile(k[active], (3, 1)))
        A = A.reshape(3, active.size, 3, 3).transpose(1, 0, 2, 3)
        k_new = solve_scale_factors(A, rate2[active], k[active])
        change = np.linalg.norm(k_new - k[active], axis=1)
        k[active] = k_new
        iters[active] = it
        done = ~(change > tol)  # converged, or NaN (unsolvable) which cannot improve
        active = active[~done]
        if active.size == 0:
            break
    iters[active] = max_iter + 1
    return k, -k * mean0, iters


def paper_batch(batch: Any) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Algorithm 1 on a simulated batch (``calib.simulator.SimBatch``), with the simulator's stage bounds."""
    k, b, iters = algorithm1_batch(batch.gyro, batch.dt, batch.still0, batch.turns)
    return k, b, {"iterations": iters}
