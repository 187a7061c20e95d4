"""The paper's Algorithm 1: biases from the first still, scale factors from three 360-degree turns.

Model (paper eq. 1): g = K m + b with K = diag(k). Steps, for each recording:

1. Bias (eq. 2). At rest g = 0, so mean_S0(m) = -b/k and b = -k * mean_S0(m) in the units of
   eq. 1 (the paper writes b = -mean(m), which is b/k; the b reported here is the b of eq. 1).
   The bias-compensated readings are m_hat = m - mean_S0(m), so g = K m_hat (eq. 3).
2. Scale factors (eq. 4-11), from K^0 = [1, 1, 1]. For each turn j the attitude is propagated
   with Rodrigues' formula (eq. 4-5) from the rates compensated with the current K^i, i.e. the
   rotation of sample t is exp([K^i m_hat_t dt]x). With C_t the attitude after sample t,
   C~_t = C_t diag(m_hat_t) (eq. 8) and G^n_t = C~_t K (eq. 9). The mean of C~_t over the turn
   (eq. 10), A_j, must give the known mean rate: ||A_j K||^2 = (theta_total / T_j)^2 (eq. 11),
   theta_total = 360 deg. The three turns give three quadratic equations in (kx, ky, kz), solved
   by Newton's method from K^i to give K^{i+1}.
3. Repeat step 2 until ||K^{i+1} - K^i|| <= tol.

Which samples a turn uses: the samples [start, end) of its stage, each held for its own sample
interval, so T_j = t[end] - t[start] (N_j sample intervals at a uniform rate), and the mean of
eq. 10 is the time-weighted mean over those samples. Then T_j * A_j = sum_t C~_t dt_t: eq. 11 says
the integrated rate in the initial frame has length 360 deg, whatever the number of samples, so
including a few still samples on either side of a turn changes nothing but noise, while cutting
off moving samples biases k. The attitude of each turn is propagated from the turn's first
sample rather than from t = 0 (eq. 5): the two differ by a constant rotation, which leaves the
norm in eq. 11 unchanged.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from calib.errors import CalibrationError, ProtocolError
from calib.io.validation import check_calibration_input
from calib.quality import Quality
from calib.recording import Recording, sample_intervals
from calib.result import CalibrationResult
from calib.stages.stage import AXES, FLAG_COUNTER_GAP, FLAG_SATURATED, Stage
from calib.units import FULL_TURN_DEG

METHOD = "paper"
TOL = 1e-5  # Algorithm 1, step 4
MAX_ITER = 50
CLOSURE_WARNDEG = 5.0  # a turn whose calibrated attitude does not come back within this is suspicious
MIN_STILL_S = 1.0  # shorter first stills give a noisy bias


# ---------------------------------------------------------------------------------------------
# eq. (11): three quadratic equations in k, solved by Newton's method (vectorised over runs)


def solve_scale_factors(A: np.ndarray, rate2: np.ndarray, k0: np.ndarray, steps: int = 30) -> np.ndarray:
    """Solve ||A_j k||^2 = rate2_j for j = 1..3 (eq. 11) by Newton's method from k0.

    A: (R, 3, 3, 3) the turn-mean matrices of eq. 10 (turn, row, column); rate2: (R, 3) the squared
    mean rates (theta_total / T_j)^2; k0: (R, 3). Returns k (R, 3); runs whose Jacobian is singular
    or whose iteration does not settle are NaN.
    """
    k = np.array(k0, dtype=float, copy=True)
    AtA = np.einsum("rjai,rjak->rjik", A, A)  # A_j^T A_j
    ok = np.ones(k.shape[0], dtype=bool)
    for _ in range(steps):
        Mk = np.einsum("rjik,rk->rji", AtA, k)
        F = np.einsum("rji,ri->rj", Mk, k) / rate2 - 1.0  # relative residual of eq. 11
        J = 2.0 * Mk / rate2[..., None]
        det = np.linalg.det(J)
        bad = ~np.isfinite(det) | (np.abs(det) < 1e-300)
        J[bad] = np.eye(3)
        step = np.linalg.solve(J, F[..., None])[..., 0]
        step[bad] = np.nan
        k = k - step
        ok &= ~bad
        if np.all(~ok | (np.abs(step) <= 1e-13 * np.maximum(1.0, np.abs(k))).all(axis=1)):
            break
    else:
        settled = (np.abs(step) <= 1e-9 * np.maximum(1.0, np.abs(k))).all(axis=1)
        ok &= settled
    k[~ok] = np.nan
    return k


# ---------------------------------------------------------------------------------------------
# Single-recording path: scipy Rotation objects


def _prefix_rotations(r: Rotation) -> Rotation:
    """Inclusive prefix products r_0 * r_1 * ... * r_t (eq. 5), by a doubling scan."""
    s = 1
    n = len(r)
    while s < n:
        r = Rotation.concatenate([r[:s], r[:-s] * r[s:]])
        s *= 2
    return r


def _turn_attitudes(m_hat: np.ndarray, dt: np.ndarray, k: np.ndarray) -> Rotation:
    """Attitudes C_t (eq. 4-5) over one turn from the compensated rates K m_hat (deg/s)."""
    return _prefix_rotations(Rotation.from_rotvec(m_hat * k * dt[:, None], degrees=True))


def _turn_mean(m_hat: np.ndarray, dt: np.ndarray, k: np.ndarray) -> np.ndarray:
    """A_j (3, 3): the time-weighted mean over the turn of C~_t = C_t diag(m_hat_t) (eq. 8, 10)."""
    C = _turn_attitudes(m_hat, dt, k).as_matrix()
    return np.einsum("tic,tc->ic", C, m_hat * dt[:, None]) / dt.sum()


@dataclass
class Algorithm1Fit:
    """Algorithm 1's result on one recording: k, b (eq. 1), iterations and the K^i of each one."""

    k: np.ndarray
    b: np.ndarray
    iterations: int
    converged: bool
    mean0: np.ndarray
    history: list[np.ndarray]


def algorithm1(
    t: np.ndarray,
    gyro: np.ndarray,
    still0: tuple[int, int],
    turns: Sequence[tuple[int, int]],
    tol: float = TOL,
    max_iter: int = MAX_ITER,
) -> Algorithm1Fit:
    """Algorithm 1 on one recording with time stamps t (s) and readings gyro (n, 3) deg/s.

    Built on scipy's Rotation and least_squares, independently of the batch path (numpy
    quaternions, Newton's method); the tests check that both give the same answer.
    """
    dt_all = sample_intervals(t)
    s0, e0 = still0
    mean0 = gyro[s0:e0].mean(axis=0)
    m_hat = gyro - mean0
    windows = [(m_hat[s:e], dt_all[s:e]) for s, e in turns]
    rate2 = np.array([(FULL_TURN_DEG / d.sum()) ** 2 for _, d in windows])
    k = np.ones(3)
    history = [k]
    converged = False
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007 - the count is returned after the loop
        A = np.stack([_turn_mean(m, d, k) for m, d in windows])
        fit = least_squares(
            lambda kk, A=A: (np.einsum("jai,i->ja", A, kk) ** 2).sum(axis=1) / rate2 - 1.0,
            k,
            jac=lambda kk, A=A: 2.0 * np.einsum("jai,jab,b->ji", A, A, kk) / rate2[:, None],
            method="lm",
            xtol=1e-15,
            ftol=1e-15,
            gtol=1e-15,
        )
        if not fit.success or not np.all(np.isfinite(fit.x)):
            raise CalibrationError(
                "the scale-factor equations (paper eq. 11) have no solution for these turns: "
                "check that each turn is a full 360-degree turn about a different axis"
            )
        change = float(np.linalg.norm(fit.x - k))
        k = fit.x
        history.append(k)
        if change <= tol:
            converged = True
            break
    return Algorithm1Fit(k=k, b=-k * mean0, iterations=it, converged=converged, mean0=mean0, history=history)



# ---------------------------------------------------------------------------------------------
# Recording -> CalibrationResult


def _protocol(rec: Recording, stages: Any) -> tuple[Stage, list[Stage], list[Stage], list[str]]:
    """(still0, [turn x, turn y, turn z], all stages, detector notes) from given or detected stages."""
    from calib.stages.resolve import resolve_stages

    resolved = resolve_stages(rec, stages)
    proto, stage_list = resolved.protocol, resolved.stages
    missing = [a for a in AXES if a not in proto.turns]
    if missing:
        raise ProtocolError(f"no full turn about {', '.join(missing)} found: turn the device 360 degrees about each axis")
    turns = [proto.turns[a] for a in AXES]  # resolve_stages checked them against the recording
    return proto.still0, turns, stage_list, list(proto.notes)


def calibrate_paper(rec: Recording, stages: Any = None) -> CalibrationResult:
    """Calibrate one recording with the paper's Algorithm 1 (method "paper").

    stages: the detected stages (list of Stage) or a ProtocolStages; detected from the data when None.
    Raises RecordingError for bad input, ProtocolError when a stage is missing, CalibrationError
    when the equations cannot be solved.
    """
    check_calibration_input(rec)
    still0, turns, stage_list, notes = _protocol(rec, stages)
    fit = algorithm1(rec.t, rec.gyro, (still0.start, still0.end), [(s.start, s.end) for s in turns])
    k, b = fit.k, fit.b
    if not np.all(k > 0):
        raise CalibrationError(
            f"Algorithm 1 gave non-positive scale factors {np.round(k, 4).tolist()}: the turns do not "
            "determine them; record one full turn about each of x, y and z"
        )

    dt_all = rec.intervals_s
    m_hat = rec.gyro - fit.mean0
    residuals: dict[str, Any] = {}
    warnings: list[str] = []
    for axis, st in zip(AXES, turns, strict=False):
        m, d = m_hat[st.start : st.end], dt_all[st.start : st.end]
        rates = m * k
        att = _turn_attitudes(m, d, k)
        integrated = np.einsum("tij,tj->i", att.as_matrix(), rates * d[:, None])  # initial-frame rotation vector
        closure = float(np.degrees(att[-1].magnitude()))
        ax = AXES.index(axis)
        residuals[axis] = {
            "angle_deg": float(np.linalg.norm(integrated)),  # eq. 11's angle: 360 at the solution
            "axis_angle_deg": float(np.sum(rates[:, ax] * d)),  # calibrated rate integrated on the turn's axis
            "closure_deg": closure,  # net attitude change over the turn: 0 if the device came back
            "duration_s": float(d.sum()),
            "samples": st.end - st.start,
        }
        if closure > CLOSURE_WARNDEG:
            warnings.append(
                f"turn about {axis}: the calibrated attitude ends {closure:.1f} deg from where it started; "
                "put the device back exactly in its starting position after each 360-degree turn"
            )
        flags = getattr(st, "flags", ())
        if FLAG_SATURATED in flags:
            warnings.append(f"turn about {axis}: readings reached the gyro's full scale; turn more slowly")
        if FLAG_COUNTER_GAP in flags:
            warnings.append(f"turn about {axis}: samples were lost during the turn; the integrated angle is short")
    still_s = float(dt_all[still0.start : still0.end].sum())
    if still_s < MIN_STILL_S:
        warnings.append(f"the first still lasts only {still_s:.1f} s: let the device rest about 3 s before turning")
    far = [f"k{a} = {v:.3g}" for a, v in zip(AXES, k, strict=False) if not 0.5 <= v <= 2.0]
    if far:
        warnings.append(f"{', '.join(far)} far from 1: check that the readings are in deg/s and the full-scale setting")
    if not fit.converged:
        warnings.append(f"Algorithm 1 did not converge within {MAX_ITER} iterations (tolerance {TOL:g})")

    quality: Quality = {
        "still0_samples": still0.end - still0.start,
        "still0_s": still_s,
        "turn_samples": {a: st.end - st.start for a, st in zip(AXES, turns, strict=False)},
        "turn_s": {a: residuals[a]["duration_s"] for a in AXES},
        "iterations": fit.iterations,
        "converged": fit.converged,
        "tolerance": TOL,
        "k_history": [[float(v) for v in kk] for kk in fit.history],
        "stage_notes": notes,
    }
    # white noise of the raw readings over the first still (deg/s of reading)
    noise = rec.gyro[still0.start : still0.end].std(axis=0, ddof=1) if still0.end - still0.start > 1 else None
    return CalibrationResult(
        k=k,
        b=b,
        method=METHOD,
        stages=stage_list,
        quality=quality,
        noise_dps=noise,
        residuals=residuals,
        warnings=warnings,
        iterations=fit.iterations,
    )


