"""The closure estimator on many simulated recordings at once (the Monte Carlo benchmark).

Same model and weights as ``calib.estimators.closure.estimator``; Gauss-Newton is vectorised across runs (each run has its
own normal equations) instead of calling scipy's least_squares once per run.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from calib.errors import RecordingError
from calib.estimators.closure.fit import ClosureData, gauss_newton, start_values
from calib.noise.rests import sensor_rests, still_statistics
from calib.numerics.windows import windows

# Runs are fitted in groups of about this many turn samples, to bound memory.
_GROUP_SAMPLES = 600_000


def closure_fit_batch(
    gyro: np.ndarray,
    dt: float,
    turns: np.ndarray,
    stills: np.ndarray,
    extended: bool = False,
) -> dict[str, np.ndarray]:
    """Fit R recordings sampled every dt seconds.

    gyro (R, n, 3) raw readings (deg/s); turns (R, J, 2) and stills (R, S, 2) sample bounds [start, end).
    Returns per-run arrays: "theta" (R, P) (k, b[, K_xy, K_xz, K_yz]), "std" (R, P) standard errors
    (inflated by the Birge ratio when the fit is worse than the noise explains), "bound" (R, P)
    Cramer-Rao bound, "chi2", "dof", "iterations", "converged", "closure_deg" (R, J, 3).
    """
    gyro = np.asarray(gyro, dtype=float)
    turns = np.asarray(turns, dtype=np.int64)
    stills = np.asarray(stills, dtype=np.int64)
    if gyro.ndim != 3 or gyro.shape[2] != 3:
        raise RecordingError(f"gyro must have shape (runs, samples, 3), got {gyro.shape}")
    R, n = gyro.shape[:2]
    if turns.ndim != 3 or turns.shape[0] != R or turns.shape[2] != 2 or stills.ndim != 3 or stills.shape[0] != R:
        raise RecordingError(f"turns and stills must have shapes ({R}, J, 2) and ({R}, S, 2); got {turns.shape} and {stills.shape}")
    if np.any(turns[..., 0] < 0) or np.any(turns[..., 1] > n) or np.any(turns[..., 1] - turns[..., 0] < 2):
        raise RecordingError(f"turn bounds must satisfy 0 <= start < end - 1 < {n}")
    if not dt > 0:
        raise RecordingError(f"dt must be a positive sample interval in seconds, got {dt}")
    out: dict[str, list[np.ndarray]] = {}
    longest = int((turns[..., 1] - turns[..., 0]).max())
    group = max(1, _GROUP_SAMPLES // (turns.shape[1] * longest))
    for lo in range(0, R, group):
        part = _fit_group(gyro[lo : lo + group], dt, turns[lo : lo + group], stills[lo : lo + group], extended)
        for key, value in part.items():
            out.setdefault(key, []).append(value)
    return {key: np.concatenate(v) for key, v in out.items()}


def _fit_group(gyro, dt, turns, stills, extended) -> dict[str, np.ndarray]:
    m, d = windows(gyro, turns, dt)
    mean, count, spread = still_statistics(gyro, stills)
    # as calibrate_closure: each recording's readings' colour counted in its noise
    colour = np.array([sensor_rests(g, [(int(a), int(b)) for a, b in st if b > a]).colour for g, st in zip(gyro, stills, strict=True)])
    data = ClosureData(m, d, mean, count, spread * np.sqrt(colour)[:, None])
    theta0, _, _ = start_values(data, extended)
    fit = gauss_newton(data, theta0, extended)
    P = theta0.shape[1]
    cov = np.full_like(fit.fisher, np.nan)
    ok = np.all(np.isfinite(fit.fisher.reshape(len(cov), -1)), axis=1)
    if ok.any():
        cov[ok] = np.linalg.pinv(fit.fisher[ok], hermitian=True)
    bound = np.sqrt(np.abs(np.einsum("rpp->rp", cov)))
    birge = np.sqrt(np.maximum(1.0, fit.chi2 / np.maximum(fit.dof, 1)))
    return {
        "theta": fit.theta,
        "std": bound * birge[:, None],
        "bound": bound.reshape(-1, P),
        "chi2": fit.chi2,
        "dof": fit.dof.astype(float),
        "iterations": fit.iterations,
        "converged": fit.converged,
        "closure_deg": np.degrees(fit.closure),
    }


def closure_batch(batch: Any) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """The closure estimator on a SimBatch, with the simulator's stage bounds: (k, b, info)."""
    res = closure_fit_batch(batch.gyro, batch.dt, batch.turns, batch.stills)
    theta = res["theta"]
    info = {
        "iterations": res["iterations"],
        "std": res["std"][:, :6],
        "bound": res["bound"][:, :6],
    }
    return theta[:, :3], theta[:, 3:6], info

