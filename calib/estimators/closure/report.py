"""The closure estimator's result: the parameters and their uncertainty from a solved fit, each turn's and each
rest's residuals, the fit's quality and the warnings a reader needs."""

from __future__ import annotations

import numpy as np

from calib.distributions import chi2_sf
from calib.errors import CalibrationError
from calib.estimators.closure.fit import ClosureData, ClosureFit, calibration_matrix, param_names
from calib.quality import Quality
from calib.recording import Recording
from calib.result import CalibrationResult
from calib.stages.stage import AXES, Stage

METHOD = "closure"
MIN_STILL_S = 1.0  # less rest than this in all gives a noisy bias
P_VALUE_WARN = 1e-3  # chi-square this improbable: the model does not explain the data
CLOSURE_WARN_SIGMA = 5.0  # a turn whose closure is this many standard errors off did not come back
OFFDIAG_WARN = 5e-3  # extended model: off-diagonal terms known worse than this are weakly identified


def closure_result(
    rec: Recording,
    stage_list: list[Stage],
    turns: list[Stage],
    stills: list[Stage],
    data: ClosureData,
    fit: ClosureFit,
    n_rev: np.ndarray,
    extended: bool,
    warnings: list[str],
    dt_all: np.ndarray,
    noise_dps: np.ndarray,
) -> CalibrationResult:
    theta = fit.theta.copy()
    names = param_names(extended)
    held = np.zeros(3, dtype=bool) if fit.not_turned is None else fit.not_turned
    try:
        cov = np.linalg.inv(fit.fisher)
    except np.linalg.LinAlgError:
        raise CalibrationError("the recording does not determine all parameters: turn the device about each axis") from None
    bound = np.sqrt(np.abs(np.diag(cov)))
    chi2 = float(fit.res @ fit.res)
    dof = int(data.dof(extended)[0]) + fit.priors  # each prior is one more observation
    learned = fit.heading is not None and fit.heading.dof is not None
    dof -= int(learned)  # the heading spread, learned from the residuals
    birge = float(np.sqrt(max(1.0, chi2 / dof))) if dof > 0 else 1.0
    p_value = float(chi2_sf(chi2, dof)) if dof > 0 else float("nan")
    std = bound * birge
    if fit.heading is not None and fit.heading.sd_ratio is not None:  # the spread learned: each variance unbiased
        std = std * fit.heading.sd_ratio
    K = calibration_matrix(theta[None])[0]
    # an axis not turned: its k only had its prior, and neither it nor its bias (the rest's reading times k) is determined
    theta[:3][held] = np.nan
    theta[3:6][held] = np.nan
    std[:6][np.concatenate((held, held))] = np.nan
    bound[:6][np.concatenate((held, held))] = np.nan

    index = {id(s): i for i, s in enumerate(stage_list)}
    J = len(turns)
    whitened = fit.res[: 3 * J].reshape(J, 3)
    turn_rows = []
    target = np.zeros((J, 3)) if data.place_target is None else data.place_target[0]
    for j, st in enumerate(turns):
        r_deg = np.degrees(fit.terms_r[j])
        miss_deg = np.degrees(fit.terms_r[j] - target[j])
        swept = fit.swept[j]
        axis = AXES.index(st.axis) if st.axis in AXES else int(np.argmax(np.abs(swept)))
        z = float(np.linalg.norm(whitened[j]))
        turn_rows.append(
            {
                "stage": index.get(id(st)),
                "axis": st.axis,
                "start_s": st.start_s,
                "end_s": st.end_s,
                "samples": st.n,
                "revolutions": int(n_rev[j]),
                "angle_deg": float(swept[axis]),  # calibrated rate integrated on the turn's axis
                # the raw readings' angle on that axis (bias from the stills removed): what the sensor said before
                "raw_angle_deg": None if st.angle_deg is None else float(st.angle_deg),
                "closure_deg": [float(v) for v in r_deg],  # net rotation over the turn: 0 when it came back
                "closure_norm_deg": float(np.linalg.norm(r_deg)),
                # the closure less the tilt the accelerometer saw the device put back with: what the turn got wrong
                "placement_deg": [float(v) for v in np.degrees(target[j])],
                "misclosure_deg": [float(v) for v in miss_deg],
                "misclosure_norm_deg": float(np.linalg.norm(miss_deg)),
                "closure_std_deg": float(np.degrees(np.sqrt(np.trace(fit.chol[j] @ fit.chol[j].T) / 3.0))),
                "z": z,
            }
        )
        if z > CLOSURE_WARN_SIGMA * np.sqrt(3.0):
            warnings.append(
                f"the turn about {st.axis} at {st.start_s:.1f} s ends {np.linalg.norm(miss_deg):.2f} deg from where it was put "
                f"back ({z / np.sqrt(3.0):.0f} times what noise and the hand explain): it may not have been one full turn, "
                "or the device was put back turned; put it back against the block after each turn"
            )
    still_rows = []
    rate = data.still_mean[0] @ K.T + theta[3:6]
    zs = fit.res[3 * J : 3 * J + 3 * len(stills)].reshape(-1, 3)  # the priors of axes not turned come after
    for s, st in enumerate(stills):
        still_rows.append(
            {
                "stage": index.get(id(st)),
                "start_s": st.start_s,
                "end_s": st.end_s,
                "samples": st.n,
                "rate_dps": [float(v) for v in rate[s]],  # calibrated mean rate: 0 at rest
                "z": [float(v) for v in zs[s]],
            }
        )
    if p_value < P_VALUE_WARN:
        warnings.append(
            f"the data fit the model worse than the noise explains (chi2/dof = {chi2 / dof:.1f}): the device may not "
            "have come back exactly to its starting pose, or its offset moved between stills; "
            f"the standard errors are scaled up by {birge:.1f}"
        )
    still_s = float(sum(dt_all[s.start : s.end].sum() for s in stills))
    if still_s < MIN_STILL_S:
        warnings.append(f"the device rested only {still_s:.1f} s in all: rest about 3 s before, between and after the turns")
    if not fit.converged:
        warnings.append("the least-squares fit stopped before converging; the result may be inaccurate")

    K_std = None
    if extended:
        K_std = np.zeros((3, 3))
        K_std[[0, 1, 2], [0, 1, 2]] = std[:3]
        K_std[[0, 0, 1], [1, 2, 2]] = std[6:9]
        offdiag_bound = bound[6:9]
        if np.any(offdiag_bound > OFFDIAG_WARN):
            warnings.append(
                "the non-orthogonality terms are only weakly determined by this recording (standard errors "
                f"{', '.join(f'{v:.1e}' for v in offdiag_bound)}); turns about axes between the sensor axes determine them better"
            )
    quality: Quality = {
        "model": "upper-triangular" if extended else "diagonal",
        "parameters": list(names),
        "chi2": chi2,
        "dof": dof,
        "birge_ratio": birge,
        "p_value": p_value,
        "turns": J,
        "stills": len(stills),
        "still_s": still_s,
        "turn_s": [float(dt_all[s.start : s.end].sum()) for s in turns],
        "stages_used": sorted(i for i in (index.get(id(s)) for s in (*turns, *stills)) if i is not None),
        "function_evaluations": fit.nfev,
        "converged": fit.converged,
        "correlation": correlation(cov).tolist(),
    }
    if held.any():
        quality["undetermined_axes"] = [a for a, h in zip(AXES, held, strict=True) if h]
    return CalibrationResult(
        k=theta[:3].copy(),
        b=theta[3:6].copy(),
        method=METHOD,
        stages=stage_list,
        quality=quality,
        k_std=std[:3],
        b_std=std[3:6],
        k_bound=bound[:3],
        b_bound=bound[3:6],
        K=K if extended else None,
        K_std=K_std,
        noise_dps=noise_dps.copy(),
        residuals={"turns": turn_rows, "stills": still_rows, "chi2": chi2, "dof": dof},
        warnings=warnings,
        iterations=fit.nfev,
        k_dof=_dof(fit, 0) if learned else None,
        b_dof=_dof(fit, 3) if learned else None,
        k_interval_scale=_scale(fit, 0) if learned else None,
        b_interval_scale=_scale(fit, 3) if learned else None,
    )


def _dof(fit: ClosureFit, first: int) -> np.ndarray:
    """The Student-t degrees of freedom of three parameters from ``first`` (inf: normal)."""
    assert fit.heading is not None and fit.heading.dof is not None  # the spread was learned
    return fit.heading.dof[first : first + 3].astype(float)


def _scale(fit: ClosureFit, first: int) -> np.ndarray | None:
    """The scale of three parameters' Student-t intervals from ``first`` (NaN: the standard error). Not widened by
    the Birge ratio as the standard errors are: the spreads it is drawn from already account for the turns'
    misclosures, which the ratio would count a second time (with it, k_z's interval held 98.2 % with no heading)."""
    assert fit.heading is not None  # the spread was learned
    scale = fit.heading.interval_scale
    return None if scale is None else scale[first : first + 3]


def correlation(cov: np.ndarray) -> np.ndarray:
    s = np.sqrt(np.abs(np.diag(cov)))
    return np.round(cov / np.outer(s, s), 6)
