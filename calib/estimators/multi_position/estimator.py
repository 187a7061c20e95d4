"""Gyroscope calibration from hand re-orientations between rests, with the accelerometer as the reference.

The maximum-likelihood estimate of g = K m + b over every constraint such a recording holds, with K a full
3x3 matrix: its diagonal the scale factors, its off-diagonal entries the gyroscope's axes relative to the
accelerometer's (non-orthogonality and the small rotation between the two sensors; the gravity
constraints see both, where the closure of a full turn sees neither):

- each rest: zero true rate, so its mean reading is -K^-1 b (the bias);
- each motion between two rests: the calibrated rotation C (body at the end to body at the start,
  ``calib.numerics.rotation.rotation_terms``) must carry the end rest's gravity direction u_e onto the
  start rest's u_s. Two constraints per motion: rho = B_s^T (C u_e - u_s), with B_s an orthonormal
  basis perpendicular to u_s (rad). The rotation about gravity is unobservable from the accelerometer
  and is left free; a motion that only turns about the vertical gives (almost) nothing;
- each full turn the stage detector finds (rests on both sides): the closure C = I, three constraints
  (as the closure estimator), instead of the two gravity ones;
- each rest's accelerometer mean: |T S (r - o)| = 1 g (``calib.estimators.accel``'s model).

The g-sensitivity G (g = K (m - G a) + b, a the specific force in g) is fitted too when the rests face enough ways
to separate it from the bias and it explains the data significantly better (an F test at ``G_ALPHA``;
``g_sensitivity=True``/``False`` forces it in or out): each rest's mean reading is then G a - K^-1 b.

Gravity directions come from the accelerometer, fitted with the gyroscope (from ``calib.estimators.accel``'s fit on
the rests alone; a given ``accel`` calibration is held fixed). Residuals are whitened by their covariance: gyro noise
through the motion (first order) plus the accelerometer's direction noise at both rests. Uncertainties are the
inverse Fisher information, scaled up by the chi-square when the data scatter more than the noise explains.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from calib.distributions import chi2_sf, f_sf
from calib.errors import CalibrationError, ProtocolError
from calib.estimators.accel import PARAMS, AccelCalibration, apply_model, calibrate_accelerometer, rest_spans
from calib.estimators.multi_position.model import (
    AccelRests,
    Data,
    Params,
    Windows,
    directions,
    gravity_misfit,
    gravity_z,
    residual_layout,
    rest_gravity,
    system,
)
from calib.io.validation import check_calibration_input
from calib.noise.accel_floor import accel_floor
from calib.noise.motion import motion_noise, no_motion_noise
from calib.noise.rests import noise_colour, still_statistics
from calib.numerics.windows import windows
from calib.quality import Quality
from calib.recording import Recording
from calib.result import CalibrationResult
from calib.stages.detector import detect_stages
from calib.stages.plateaus import clipped_spans
from calib.stages.recognise import MIN_MOTIONS
from calib.stages.stage import Stage

MAX_GRAVITY_RMS_DEG = 2.0  # gravity residuals (rms) beyond which the re-orientations fit no calibration
# ... and this many times that without a g-sensitivity, beyond what one could take away: a MEMS gyro's 0.1 (deg/s)/g
# (datasheets) moves a few seconds' motion by tenths of a degree
G_RESCUE = 3.0
MAX_ITERATIONS = 50  # steps tried, the damped ones counted
G_ALPHA = 1e-3  # false-positive rate of the g-sensitivity's F test on a sensor that has none
G_SPREAD_MIN = 0.25  # the rests' gravity directions must spread at least this much (rms, per principal axis)


@dataclass(frozen=True)
class Motion:
    """A motion between two consecutive rests."""

    start: int  # first sample after the start rest
    end: int  # first sample of the end rest
    rest_before: int  # index into the stills
    rest_after: int
    full_turn: Stage | None  # the detected full turn, when the motion is one


@dataclass(frozen=True)
class _Fit:
    p: Params
    res: np.ndarray
    jac: np.ndarray

    @property
    def chi2(self) -> float:
        return float(self.res @ self.res)

    @property
    def dof(self) -> int:
        return self.res.size - self.jac.shape[1]

    @property
    def birge(self) -> float:
        return float(np.sqrt(max(1.0, self.chi2 / self.dof))) if self.dof > 0 else 1.0


def motions_between_rests(stages: list[Stage]) -> tuple[list[Stage], list[Motion]]:
    """The stills of ``stages`` and every motion between two consecutive ones."""
    stills = [s for s in stages if s.kind == "still"]
    out = []
    for i in range(len(stills) - 1):
        a, b = stills[i], stills[i + 1]
        if b.start <= a.end:
            continue
        between = [s for s in stages if s.start >= a.end and s.end <= b.start and s.kind != "still"]
        turn = between[0] if len(between) == 1 and between[0].kind == "turn" else None
        out.append(Motion(a.end, b.start, i, i + 1, turn))
    return stills, out


def gravity_motions(motions: list[Motion]) -> list[Motion]:
    """The motions constrained by the gravity directions at their ends (those that are not full turns), in order."""
    return [mo for mo in motions if mo.full_turn is None]


def calibrate_multi_position(rec: Recording, stages: Any = None, accel: AccelCalibration | None = None,
                             g_sensitivity: bool | None = None, motion_noise: bool = True) -> CalibrationResult:
    """Calibrate from rests and the motions between them (method "multi-position"); needs the accelerometer.

    ``stages``: a list of Stage, or None to detect them. ``accel``: the accelerometer's calibration, or
    None to fit it on the same rests. ``g_sensitivity``: fit G (True), not (False), or when identified and
    significant (None). ``motion_noise``: measure the gyro's noise while moving and count it where beyond chance
    (True), or take the motions' noise as the rests' (False). Raises ProtocolError when the recording has too few
    rests or re-orientations, CalibrationError when they do not determine k and b (or G, when asked for).
    """
    check_calibration_input(rec)
    if rec.accel is None:
        raise ProtocolError("calibrating from re-orientations needs the accelerometer: record its channel with the gyroscope")
    stage_list = list(stages) if stages is not None else detect_stages(rec)
    stills, motions = motions_between_rests(stage_list)
    hit = set(np.flatnonzero(clipped_spans(rec, [(m.start, m.end) for m in motions])))  # clipped: their rotation is short
    clipped, motions = [m for i, m in enumerate(motions) if i in hit], [m for i, m in enumerate(motions) if i not in hit]
    if len(motions) < MIN_MOTIONS:
        raise ProtocolError(f"the recording has {len(motions)} motion(s) between rests{_clipped_words(rec, clipped, ' besides')}; "
                            f"calibrating from re-orientations needs at least {MIN_MOTIONS}: rest the device a few seconds, "
                            "turn it to a new orientation, rest again, and so on")
    joint = accel is None  # fit the accelerometer with the gyroscope, from a first fit on the rests alone
    accel = accel or calibrate_accelerometer(rec, stills)
    free_a = np.array([p in accel.identified for p in PARAMS]) if joint else np.zeros(9, dtype=bool)
    data = _data(rec, stills, motions, free_a, motion_noise)
    base = _fit(Params(np.eye(3), -data.mean[0], None, accel.vector.copy()), data)
    if g_sensitivity is not False and _off(base, data, G_RESCUE):
        # a large g-sensitivity can lead the iteration from the identity to a far minimum; not from where a fit with it ends
        with_g = _fit(Params(np.eye(3), -data.mean[0], np.zeros((3, 3)), accel.vector.copy()), data)
        if _off(with_g, data) is None:
            base = _fit(Params(with_g.p.K, with_g.p.b, None, with_g.p.xa.copy()), data)
    _check_agreement(base, data, G_RESCUE)  # so far off that no g-sensitivity could mend it: refused before fitting one
    fit, g_test = _g_sensitivity_choice(base, data, g_sensitivity)
    _check_agreement(fit, data)
    result = _result(fit, g_test, base, data, accel, joint, stage_list, rec, _motion_times(rec, motions))
    if clipped:
        result.warnings.append(_clipped_words(rec, clipped, "") + " are not used: turn more slowly")
    return result


def _clipped_words(rec: Recording, clipped: list[Motion], lead: str) -> str:
    """"N re-orientations that reached the gyro's full scale (at 52.3, 63.6, ... s)", after ``lead``; "" for none."""
    at = ", ".join(f"{rec.t[m.start] - rec.t[0]:.1f}" for m in clipped[:6]) + (", ..." if len(clipped) > 6 else "")
    n = f"{lead} {len(clipped)}" if lead else f"{len(clipped)}"
    return f"{n} re-orientation{'s' if len(clipped) > 1 else ''} that reached the gyro's full scale (at {at} s)" if clipped else ""


def _data(rec: Recording, stills: list[Stage], motions: list[Motion], free_a: np.ndarray, measure_motion_noise: bool = True
          ) -> Data:
    assert rec.accel is not None
    dt_all = rec.intervals_s[None]
    gyro, acc = rec.gyro[None], rec.accel[None]
    mean, count, sigma = still_statistics(gyro, np.array([[[s.start, s.end] for s in stills]]))
    colour = noise_colour(rec.gyro, [(s.start, s.end) for s in stills])
    spans = rest_spans(stills, rec.fs)
    accel_colours = noise_colour(rec.accel, spans)
    accel_colour = float(np.mean(accel_colours))  # its rest means scatter by this much more, too
    rests = AccelRests(
        mean=np.array([rec.accel[i:j].mean(axis=0) for i, j in spans]),
        sd=np.maximum(np.array([rec.accel[i:j].std(axis=0).mean() for i, j in spans]), 1e-4) * np.sqrt(accel_colour),
        n=np.array([j - i for i, j in spans], dtype=float),
        drift=np.array([_thirds_drift(rec.accel[i:j]) for i, j in spans]),
        seconds=np.array([rec.t[j - 1] - rec.t[i] for i, j in spans]) + 1.0 / rec.fs,
        floor=accel_floor(rec.accel, spans, accel_colours, rec.fs),
    )
    grav = gravity_motions(motions)
    turns = [mo for mo in motions if mo.full_turn is not None]
    moving = [(spans[mo.rest_before][1], spans[mo.rest_after][0]) for mo in grav] + [(mo.start, mo.end) for mo in turns]

    def stacked(bounds: list[list[int]]) -> Windows | None:
        if not bounds:
            return None
        b = np.array([bounds])
        m, d = windows(gyro, b, dt_all)
        a, _ = windows(acc, b, dt_all)
        return Windows(m, a, d)

    # integrate from where the rest before stops being averaged to where the rest after starts: the motion's slow
    # start and end, which the stage detector counts as rest, are then inside the window (the true rate there is ~0)
    return Data(
        mean=mean[0], count=count[0], sigma=sigma[0], sigma_slow=sigma[0] * np.sqrt(colour),
        motion_noise=motion_noise(rec.gyro, spans, moving, rec.fs) if measure_motion_noise
        else no_motion_noise(rec.fs, "not asked for"),
        gravity=stacked([[spans[mo.rest_before][1], spans[mo.rest_after][0]] for mo in grav]),
        turns=stacked([[mo.start, mo.end] for mo in turns]),
        pairs=(np.array([mo.rest_before for mo in grav], dtype=int), np.array([mo.rest_after for mo in grav], dtype=int)),
        rests=rests, free_a=free_a,
    )


def _thirds_drift(readings: np.ndarray) -> np.ndarray:
    """Mean of the last third minus mean of the first third."""
    third = len(readings) // 3
    return readings[-third:].mean(axis=0) - readings[:third].mean(axis=0)


def _fit(p: Params, data: Data) -> _Fit:
    """Levenberg-Marquardt from ``p``; CalibrationError when the constraints do not determine every parameter.

    Damped because a long motion integrated with the starting scale factors can end tens of degrees off, where
    a full Gauss-Newton step overshoots (the misfit is far from linear there) and the iteration diverges."""
    res, jac = system(p, data)
    chi2, damping = float(res @ res), 0.0
    for _ in range(MAX_ITERATIONS):
        step = _damped_step(jac, res, damping)
        trial = p.stepped(step, data.free_a)
        res_t, jac_t = system(trial, data)
        chi2_t = float(res_t @ res_t)
        if not np.isfinite(chi2_t) or chi2_t > chi2 * (1 + 1e-12):
            damping = max(10.0 * damping, 1e-3)
            continue
        p, res, jac, chi2, damping = trial, res_t, jac_t, chi2_t, damping / 10.0
        if np.all(np.abs(step[:9]) < 1e-10) and np.all(np.abs(step[9:]) < 1e-8):
            break
    sv = np.linalg.svd(jac, compute_uv=False)
    if sv[-1] <= 0 or sv[0] / sv[-1] > 1e8:
        raise CalibrationError("the re-orientations do not determine every entry of K: turn the device so that each of its "
                               "axes is tilted (not only turned about the vertical) in several of the motions")
    return _Fit(p, res, jac)


def _damped_step(jac: np.ndarray, res: np.ndarray, damping: float) -> np.ndarray:
    """The Gauss-Newton step (``damping`` 0), or Levenberg-Marquardt's with the normal matrix's diagonal scaled
    by 1 + ``damping``."""
    if damping == 0.0:
        return np.linalg.lstsq(jac, -res, rcond=None)[0]
    scale = np.sqrt(damping * np.sum(jac**2, axis=0))
    augmented = np.vstack([jac, np.diag(scale)])
    return np.linalg.lstsq(augmented, np.concatenate([-res, np.zeros(scale.size)]), rcond=None)[0]


def _g_sensitivity_choice(base: _Fit, data: Data, asked: bool | None) -> tuple[_Fit, dict[str, Any]]:
    """The fit to report and the g-sensitivity's test: fitted when asked, or (``asked`` None) when the rests
    separate it from the bias and the F test finds it at ``G_ALPHA``."""
    u, _, _ = directions(base.p.xa, data.rests)
    spread = float(np.linalg.svd(u - u.mean(axis=0), compute_uv=False)[-1] / np.sqrt(len(u)))
    test: dict[str, Any] = {"fitted": False, "asked": asked, "rest_direction_spread": spread,
                            "without": {"chi2": base.chi2, "dof": base.dof, "birge_ratio": base.birge}}
    if asked is False:
        test["reason"] = "not asked for"
        return base, test
    if spread < G_SPREAD_MIN:
        reason = (f"the rests face too few ways to separate the g-sensitivity from the bias (spread {spread:.2f}, "
                  f"needs {G_SPREAD_MIN}): rest the device on each of its faces")
        if asked:
            raise CalibrationError(reason)
        test["reason"] = reason
        return base, test
    with_g = _fit(Params(base.p.K, base.p.b, np.zeros((3, 3)), base.p.xa.copy()), data)
    F = (base.chi2 - with_g.chi2) / 9.0 / (with_g.chi2 / with_g.dof)
    p_value = float(f_sf(F, 9, with_g.dof))
    test.update(F=float(F), p_value=p_value)
    if asked or p_value < G_ALPHA:
        test.update(fitted=True, reason="asked for" if asked else f"significant (p = {p_value:.2g} < {G_ALPHA:g})")
        return with_g, test
    test["reason"] = f"not significant (p = {p_value:.2g} >= {G_ALPHA:g})"
    return base, test


def _off(fit: _Fit, data: Data, slack: float = 1.0) -> float | None:
    """The gravity residuals' rms (deg) when over ``slack`` times ``MAX_GRAVITY_RMS_DEG``, else None."""
    rms = _rms(_gravity_deg(fit.p, data))
    return rms if rms is not None and rms > MAX_GRAVITY_RMS_DEG * slack else None


def _check_agreement(fit: _Fit, data: Data, slack: float = 1.0) -> None:
    """CalibrationError when the motions still carry gravity too far off at the best fit (``_off``): no gyro calibration
    explains them (a wrong sample rate, the accelerometer's axes not the gyro's, motions that are not between rests)."""
    if (rms := _off(fit, data, slack)) is not None:
        raise CalibrationError(
            f"no calibration makes the re-orientations agree with the accelerometer: at the best fit, gravity is still "
            f"{rms:.1f} deg rms off after them (a calibrated gyro leaves a few tenths at most). Check the sample rate, "
            "that the accelerometer's axes are the gyro's, and that the device rested between the re-orientations",
            code="reorientations_disagree")


def _gravity_deg(p: Params, data: Data) -> np.ndarray:
    if data.gravity is None:
        return np.zeros(0)
    return np.degrees(np.linalg.norm(gravity_misfit(p, data), axis=1))


def _settling_report(p: Params, data: Data) -> dict[str, Any]:
    """The rests that were still settling: their gravity's drift across itself between their first and last thirds
    (deg), counted in their directions' noise where it is beyond chance."""
    gravity = rest_gravity(p.xa, data.rests)
    drift_deg = np.degrees(np.sqrt(2.0 * gravity.across))
    return {"rests_counted": [int(i) for i in np.flatnonzero(gravity.counted_across)],
            "drift_deg": [float(v) for v in drift_deg], "largest_deg": float(drift_deg.max()) if drift_deg.size else None}


def _constraint_fit(fit: _Fit, cov: np.ndarray, data: Data) -> dict[str, dict[str, Any]]:
    """Per kind of constraint (``residual_layout``): its whitened chi-square against what noise alone gives it, the
    equations less the share of the fitted parameters they carry (their leverages' sum, ``cov`` the parameters'
    inverse Fisher information), with the chance of a chi-square that large. A kind well above 1 is where the
    model or the noise falls short."""
    leverage = np.einsum("ij,jk,ik->i", fit.jac, cov, fit.jac)
    out: dict[str, dict[str, Any]] = {}
    start = 0
    for kind, size in residual_layout(data).items():
        rows = slice(start, start + size)
        start += size
        if size == 0:
            continue
        chi2 = float(fit.res[rows] @ fit.res[rows])
        expected = float(size - leverage[rows].sum())
        out[kind] = {"equations": size, "chi2": chi2, "expected": expected, "ratio": chi2 / expected if expected > 0 else None,
                     "p_value": float(chi2_sf(chi2, expected)) if expected > 0 else None}
    return out


def _motion_times(rec: Recording, motions: list[Motion]) -> list[list[float]]:
    """[start, end] s of each motion the gravity residuals are of, in their order."""
    last = len(rec) - 1
    return [[float(rec.t[min(mo.start, last)]), float(rec.t[min(mo.end, last)])] for mo in gravity_motions(motions)]


def _rms(v: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(v**2))) if v.size else None


def _result(fit: _Fit, g_test: dict[str, Any], base: _Fit, data: Data, accel: AccelCalibration, joint: bool,
            stage_list: list[Stage], rec: Recording, motion_times: list[list[float]]) -> CalibrationResult:
    p = fit.p
    cov = np.linalg.inv(fit.jac.T @ fit.jac)
    bound = np.sqrt(np.diag(cov))
    std = bound * fit.birge
    ng = p.n_gyro
    n_grav = data.pairs[0].size
    gravity_deg = _gravity_deg(p, data)
    without_deg = gravity_deg if fit is base else _gravity_deg(base.p, data)
    g_test["without"]["gravity_residual_rms_deg"] = _rms(without_deg)
    if joint:
        a_std = np.full(9, np.nan)
        a_std[data.free_a] = std[ng:]
        mag = np.linalg.norm(apply_model(p.xa, data.rests.mean), axis=1) - 1.0
        note = (accel.note + "; " if accel.note else "") + "fitted with the gyroscope (rests and re-orientations together)"
        accel = AccelCalibration.from_fit(p.xa, a_std, data.free_a, mag, note)
    quality: Quality = {
        "constraints": {"rests": data.mean.shape[0], "gravity_motions": n_grav,
                        "full_turns": 0 if data.turns is None else data.turns.dt.shape[1]},
        "chi2": fit.chi2, "dof": fit.dof, "birge_ratio": fit.birge,
        "gravity_residual_deg": [float(v) for v in gravity_deg],
        "gravity_motions_s": motion_times,
        "gravity_residual_rms_deg": _rms(gravity_deg),
        "gravity_z": [float(v) for v in gravity_z(p, data)] if n_grav else [],
        "accelerometer": accel.to_dict(),
        "g_sensitivity": g_test,
        "settling": _settling_report(p, data),
        "accelerometer_floor": data.rests.floor.to_dict(),
        "gyro_motion_noise": data.motion_noise.to_dict(),
        "constraint_fit": _constraint_fit(fit, cov, data),
    }
    diag = np.array([0, 4, 8])
    return CalibrationResult(
        k=np.diag(p.K).copy(), b=p.b, method="multi-position", stages=stage_list, quality=quality,
        k_std=std[diag], b_std=std[9:12], k_bound=bound[diag], b_bound=bound[9:12], K=p.K, K_std=std[:9].reshape(3, 3),
        noise_dps=data.sigma, sample_rate_hz=rec.fs, n_samples=len(rec),
        G=p.G, G_std=None if p.G is None else std[12:21].reshape(3, 3),
    )
