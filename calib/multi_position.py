"""Gyroscope calibration from hand re-orientations between rests, with the accelerometer as the reference.

The maximum-likelihood estimate of g = K m + b over every constraint such a recording holds, with K a full
3x3 matrix: its diagonal the scale factors, its off-diagonal entries the gyroscope's axes relative to the
accelerometer's (non-orthogonality and the small rotation between the two sensors; the gravity
constraints see both, where the closure of a full turn sees neither):

- each rest: zero true rate, so its mean reading is -K^-1 b (the bias);
- each motion between two rests: the calibrated rotation C (body at the end to body at the start,
  ``calib.closure_model.rotation_terms``) must carry the end rest's gravity direction u_e onto the
  start rest's u_s. Two constraints per motion: rho = B_s^T (C u_e - u_s), with B_s an orthonormal
  basis perpendicular to u_s (rad). The rotation about gravity is unobservable from the accelerometer
  and is left free; a motion that only turns about the vertical gives (almost) nothing;
- each full turn the stage detector finds (rests on both sides): the closure C = I, three constraints
  (as the closure estimator), instead of the two gravity ones;
- each rest's accelerometer mean: |T S (r - o)| = 1 g (``calib.accel``'s model).

Gravity directions come from the accelerometer, fitted together with the gyroscope (started from
``calib.accel``'s fit on the rests alone; given an ``accel`` calibration, that one is held fixed). Each
residual is whitened by its covariance: gyro reading noise propagated through the motion (first order,
as the closure model does) plus the accelerometer's direction noise at both rests. Uncertainties are
the inverse Fisher information, scaled up by the fit's chi-square when the data scatter more than the
noise explains (the hand, physics the model leaves out).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .accel import PARAMS, AccelCalibration, apply_model, calibrate_accelerometer, rest_spans
from .closure_fit import still_statistics, windows
from .closure_model import closure_terms, rotation_terms
from .errors import CalibrationError, ProtocolError
from .recording import Recording, sample_intervals
from .result import CalibrationResult
from .stage import Stage
from .stages import detect_stages
from .validation import check_calibration_input

MIN_MOTIONS = 6  # re-orientations needed before the three scale factors can be separated
MAX_ITERATIONS = 30


@dataclass(frozen=True)
class _Motion:
    start: int  # first sample after the start rest
    end: int  # first sample of the end rest
    rest_before: int  # index into the stills
    rest_after: int
    full_turn: Stage | None  # the detected full turn, when the motion is one


def _skew(v: np.ndarray) -> np.ndarray:
    x, y, z = np.moveaxis(v, -1, 0)
    zero = np.zeros_like(x)
    return np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2)


def _perp_basis(u: np.ndarray) -> np.ndarray:
    """(N, 3, 2): two orthonormal vectors perpendicular to each unit vector u (N, 3)."""
    helper = np.where(np.abs(u[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(u, e1)
    return np.stack([e1, e2], axis=-1)


def _motions(stages: list[Stage]) -> tuple[list[Stage], list[_Motion]]:
    stills = [s for s in stages if s.kind == "still"]
    out = []
    for i in range(len(stills) - 1):
        a, b = stills[i], stills[i + 1]
        if b.start <= a.end:
            continue
        between = [s for s in stages if s.start >= a.end and s.end <= b.start and s.kind != "still"]
        turn = between[0] if len(between) == 1 and between[0].kind == "turn" else None
        out.append(_Motion(a.end, b.start, i, i + 1, turn))
    return stills, out


def calibrate_multi_position(rec: Recording, stages: Any = None, accel: AccelCalibration | None = None) -> CalibrationResult:
    """Calibrate from rests and the motions between them (method "multi-position"); needs the accelerometer.

    ``stages``: a list of Stage, or None to detect them. ``accel``: the accelerometer's calibration, or
    None to fit it on the same rests. Raises ProtocolError when the recording has too few rests or
    re-orientations, CalibrationError when they do not determine k and b.
    """
    check_calibration_input(rec)
    if rec.accel is None:
        raise ProtocolError("calibrating from re-orientations needs the accelerometer: record its channel with the gyroscope")
    stage_list = list(stages) if stages is not None else detect_stages(rec)
    stills, motions = _motions(stage_list)
    if len(motions) < MIN_MOTIONS:
        raise ProtocolError(
            f"the recording has {len(motions)} motions between rests; calibrating from re-orientations needs at least "
            f"{MIN_MOTIONS}: rest the device a few seconds, turn it to a new orientation, rest again, and so on")
    joint = accel is None  # fit the accelerometer with the gyroscope, from a first fit on the rests alone
    accel = accel or calibrate_accelerometer(rec, stills)
    dt_all = sample_intervals(rec.t)
    gyro = rec.gyro[None]

    mean, count, sigma = still_statistics(gyro, np.array([[[s.start, s.end] for s in stills]]))
    mean, count, sigma = mean[0], count[0], sigma[0]
    spans = rest_spans(stills, rec.fs)
    rests = _AccelRests(
        mean=np.array([rec.accel[i:j].mean(axis=0) for i, j in spans]),
        sd=np.maximum(np.array([rec.accel[i:j].std(axis=0).mean() for i, j in spans]), 1e-4),
        n=np.array([j - i for i, j in spans], dtype=float),
    )
    xa = accel.vector
    free_a = np.array([p in accel.identified for p in PARAMS]) if joint else np.zeros(9, dtype=bool)

    grav = [mo for mo in motions if mo.full_turn is None]
    turns = [mo for mo in motions if mo.full_turn is not None]
    # integrate from where the rest before stops being averaged to where the rest after starts: the motion's slow
    # start and end, which the stage detector counts as rest, are then inside the window (the true rate there is ~0)
    bounds = [[spans[mo.rest_before][1], spans[mo.rest_after][0]] for mo in grav]
    mg, dg = windows(gyro, np.array([bounds]), dt_all[None]) if grav else (None, None)
    mt, dtt = windows(gyro, np.array([[[mo.start, mo.end] for mo in turns]]), dt_all[None]) if turns else (None, None)
    pairs = (np.array([mo.rest_before for mo in grav], dtype=int), np.array([mo.rest_after for mo in grav], dtype=int))
    data = _Data(mean, count, sigma, mg, dg, mt, dtt, pairs, rests, free_a)

    K, b = np.eye(3), -mean[0]
    for _ in range(MAX_ITERATIONS):
        res, jac = _system(K, b, xa, data)
        step, *_ = np.linalg.lstsq(jac, -res, rcond=None)
        K, b = K + step[:9].reshape(3, 3), b + step[9:12]
        xa[free_a] += step[12:]
        if np.all(np.abs(step[:9]) < 1e-10) and np.all(np.abs(step[9:]) < 1e-8):
            break
    res, jac = _system(K, b, xa, data)
    fisher = jac.T @ jac
    sv = np.linalg.svd(jac, compute_uv=False)
    if sv[-1] <= 0 or sv[0] / sv[-1] > 1e8:
        raise CalibrationError("the re-orientations do not determine every entry of K: turn the device so that each of its "
                               "axes is tilted (not only turned about the vertical) in several of the motions")
    cov = np.linalg.inv(fisher)
    bound = np.sqrt(np.diag(cov))
    chi2 = float(res @ res)
    dof = res.size - jac.shape[1]
    birge = float(np.sqrt(max(1.0, chi2 / dof))) if dof > 0 else 1.0
    std = bound * birge
    G = len(grav)
    rho = res[: 2 * G].reshape(G, 2)
    gravity_deg = np.degrees(np.linalg.norm(_gravity_misfit(K, b, xa, data), axis=1)) if grav else np.zeros(0)
    if joint:
        a_std = np.full(9, np.nan)
        a_std[free_a] = std[12:]
        mag = np.linalg.norm(apply_model(xa, rests.mean), axis=1) - 1.0
        note = (accel.note + "; " if accel.note else "") + "fitted with the gyroscope (rests and re-orientations together)"
        accel = AccelCalibration.from_fit(xa, a_std, free_a, mag, note)
    quality = {
        "constraints": {"rests": len(stills), "gravity_motions": G, "full_turns": len(turns)},
        "chi2": chi2, "dof": dof, "birge_ratio": birge,
        "gravity_residual_deg": [float(v) for v in gravity_deg],
        "gravity_residual_rms_deg": float(np.sqrt(np.mean(gravity_deg**2))) if G else None,
        "gravity_z": [float(v) for v in np.linalg.norm(rho, axis=1)],
        "accelerometer": accel.to_dict(),
    }
    diag = np.array([0, 4, 8])
    return CalibrationResult(
        k=np.diag(K).copy(), b=b, method="multi-position", stages=stage_list, quality=quality,
        k_std=std[diag], b_std=std[9:12], k_bound=bound[diag], b_bound=bound[9:12], K=K, K_std=std[:9].reshape(3, 3),
        noise_dps=sigma, sample_rate_hz=rec.fs, n_samples=len(rec),
    )


@dataclass(frozen=True)
class _AccelRests:
    mean: np.ndarray  # (N, 3) raw mean reading of each rest, g
    sd: np.ndarray  # (N,) its within-rest std (mean over axes), g
    n: np.ndarray  # (N,) samples averaged


@dataclass(frozen=True)
class _Data:
    mean: np.ndarray  # (S, 3) gyro mean of each rest
    count: np.ndarray
    sigma: np.ndarray  # (3,) gyro reading noise
    mg: np.ndarray | None  # gravity motions' windows
    dg: np.ndarray | None
    mt: np.ndarray | None  # full turns' windows
    dtt: np.ndarray | None
    pairs: tuple[np.ndarray, np.ndarray]  # rest before and after each gravity motion
    rests: _AccelRests
    free_a: np.ndarray  # (9,) accelerometer parameters fitted jointly


def _directions(xa: np.ndarray, rests: _AccelRests) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit gravity directions (N, 3), their noise variance per component (rad^2) and |a| - 1 whitened."""
    a = apply_model(xa, rests.mean)
    norm = np.linalg.norm(a, axis=1)
    sd_g = rests.sd * float(np.mean(np.abs(xa[0:3]))) / np.sqrt(rests.n)
    return a / norm[:, None], (sd_g / norm) ** 2, (norm - 1.0) / sd_g


def _rotations(K, b, data: _Data, noise: bool):
    G = data.pairs[0].size
    assert data.mg is not None and data.dg is not None
    return rotation_terms(data.mg, data.dg, np.broadcast_to(K, (G, 3, 3)).copy(), np.broadcast_to(b, (G, 3)).copy(),
                          sigma=np.broadcast_to(data.sigma, (G, 3)).copy() if noise else None)


def _gravity_misfit(K, b, xa, data: _Data) -> np.ndarray:
    """(G, 2) rad: the end rest's gravity carried to the start, minus the start's, perpendicular to it."""
    u, _, _ = _directions(xa, data.rests)
    i_s, i_e = data.pairs
    C = _rotations(K, b, data, noise=False).C
    return np.einsum("gia,gi->ga", _perp_basis(u[i_s]), np.einsum("gij,gj->gi", C, u[i_e]) - u[i_s])


FD_STEP = 1e-6  # central-difference step of the accelerometer parameters


def _accel_differences(xa: np.ndarray, data: _Data) -> tuple[np.ndarray, np.ndarray]:
    """For each free accelerometer parameter, by central differences: the change of the gravity directions
    (F, N, 3) over +-FD_STEP (not yet divided by 2 FD_STEP), and d(whitened |a| - 1)/d parameter (F, N)."""
    free = np.flatnonzero(data.free_a)
    du = np.zeros((free.size, data.rests.n.size, 3))
    dmag = np.zeros((free.size, data.rests.n.size))
    for c, p in enumerate(free):
        xp, xm = xa.copy(), xa.copy()
        xp[p] += FD_STEP
        xm[p] -= FD_STEP
        (up, _, mp), (um, _, mm) = _directions(xp, data.rests), _directions(xm, data.rests)
        du[c] = up - um
        dmag[c] = (mp - mm) / (2 * FD_STEP)
    return du, dmag


def _system(K, b, xa, data: _Data) -> tuple[np.ndarray, np.ndarray]:
    """Whitened residuals and Jacobian over (K row-major, b, the free accelerometer parameters):
    gravity motions, full turns, gyro rests, accelerometer magnitudes."""
    free = np.flatnonzero(data.free_a)
    P = 12 + free.size
    res_parts, jac_parts = [], []
    u, dvar, mag = _directions(xa, data.rests)
    du, dmag = _accel_differences(xa, data)
    if data.mg is not None:
        i_s, i_e = data.pairs
        rt = _rotations(K, b, data, noise=True)
        B = _perp_basis(u[i_s])
        v = np.einsum("gij,gj->gi", rt.C, u[i_e])
        rho = np.einsum("gia,gi->ga", B, v - u[i_s])
        Pm = -np.einsum("gia,gij->gaj", B, _skew(v))  # d rho / d phi (G, 2, 3)
        G = rho.shape[0]
        dgyro = Pm @ np.concatenate([rt.dK.reshape(G, 3, 9), rt.db], axis=-1)  # (G, 2, 12)
        assert rt.noise is not None
        cov = Pm @ rt.noise @ Pm.transpose(0, 2, 1) + (dvar[i_s] + dvar[i_e])[:, None, None] * np.eye(2)
        L = np.linalg.cholesky(cov)
        dacc = np.zeros((G, 2, free.size))
        for c in range(free.size):  # the directions' dependence on the accelerometer
            dv = np.einsum("gij,gj->gi", rt.C, du[c][i_e]) - du[c][i_s]
            dacc[:, :, c] = np.einsum("gia,gi->ga", B, dv) / (2 * FD_STEP)
        res_parts.append(np.linalg.solve(L, rho[..., None])[..., 0].reshape(-1))
        jac_parts.append(np.linalg.solve(L, np.concatenate([dgyro, dacc], axis=-1)).reshape(-1, P))
    if data.mt is not None and data.dtt is not None:
        T = data.mt.shape[1]
        ct = closure_terms(data.mt, data.dtt, np.broadcast_to(K, (T, 3, 3)).copy(), np.broadcast_to(b, (T, 3)).copy(),
                           sigma=np.broadcast_to(data.sigma, (T, 3)).copy())
        assert ct.dK is not None and ct.db is not None and ct.noise is not None
        d = np.concatenate([ct.dK.reshape(T, 3, 9), ct.db, np.zeros((T, 3, free.size))], axis=-1)
        L = np.linalg.cholesky(ct.noise)
        res_parts.append(np.linalg.solve(L, ct.r[..., None])[..., 0].reshape(-1))
        jac_parts.append(np.linalg.solve(L, d).reshape(-1, P))
    # gyro rests: the mean reading is -beta, beta = K^-1 b
    Kinv = np.linalg.inv(K)
    beta = Kinv @ b
    w = np.sqrt(data.count)[:, None] / data.sigma[None, :]
    res_parts.append((w * (data.mean + beta)).reshape(-1))
    dbeta = np.zeros((3, P))
    for i in range(3):
        for j in range(3):
            dbeta[:, 3 * i + j] = -Kinv[:, i] * beta[j]
    dbeta[:, 9:12] = Kinv
    jac_parts.append((w[..., None] * dbeta[None]).reshape(-1, P))
    if free.size:  # accelerometer rests: |a| = 1 g
        jmag = np.zeros((mag.size, P))
        jmag[:, 12:] = dmag.T
        res_parts.append(mag)
        jac_parts.append(jmag)
    return np.concatenate(res_parts), np.concatenate(jac_parts)
