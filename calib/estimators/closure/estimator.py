"""The closure estimator (method "closure", gyrocal's default): maximum likelihood over K and b.

Physics: after a full hand turn the device is back in the pose it started from, so the product of
the calibrated incremental rotations over the turn is the identity, with a swept angle of 360 deg per
revolution. Each turn gives the 3-D closing rotation r_j = Log(prod_t Exp((K m_t + b) dt_t)), which
must be 0; each still segment gives its mean reading, which must be -K^-1 b. Both are weighted by the
covariance the reading noise gives them (its level and its colour, the correlation of neighbouring readings a
sensor's own filter leaves, come from the stills), and the weighted
sum of squares is minimised by Gauss-Newton with the analytic Jacobian (calib.numerics.rotation,
calib.estimators.closure.fit), or by scipy.optimize.least_squares where its steps do not settle. Any number of
turns, in either direction, about any axis.

Uncertainty: the inverse of J^T J (whitened Jacobian at the solution) is the Cramer-Rao bound for the
recording; the reported standard errors are that bound scaled by the Birge ratio sqrt(chi2/dof) when
the residuals are larger than the noise explains (never scaled down).

Extended model (``extended=True``): K upper-triangular, adding the three non-orthogonality terms
K_xy, K_xz, K_yz. They are observable only when the turns are not all about fixed axes (hand wobble)
or when some turns are about axes between the sensor axes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from calib.distributions import chi2_sf
from calib.errors import CalibrationError, ProtocolError
from calib.estimators.closure.fit import (
    OFF_DIAGONAL,
    ClosureData,
    ClosureFit,
    KPrior,
    System,
    assemble,
    bias_free_angles,
    start_values,
    system,
)
from calib.estimators.closure.heading import HeadingEvidence, heading_evidence, heading_report, learn_heading
from calib.estimators.closure.partial import not_turned_text, partial_start, turned_axes
from calib.estimators.closure.placement import HEADING_PRIOR_DEG, HeadingSpread, check_heading_prior, placement_model
from calib.estimators.closure.report import OFFDIAG_WARN, closure_result
from calib.io.validation import check_calibration_input
from calib.noise.rests import rest_readings, still_statistics
from calib.numerics.rotation import ClosureTerms
from calib.numerics.windows import windows
from calib.quality import ModelChoice
from calib.recording import Recording
from calib.result import CalibrationResult
from calib.stages.placement import measure_tilts, placement_report
from calib.stages.stage import FLAG_COUNTER_GAP, FLAG_SATURATED, Stage
from calib.units import FULL_TURN_DEG

MIN_STILL_SAMPLES = 2
MAX_CLOSURE_DEG = 45.0  # a turn that still misses its start by this much after the fit was not a full turn
NOT_TURNED_K_SD = 0.1  # an axis not turned: its scale factor's prior, a working MEMS gyroscope's 0.8-1.2 at 2 sigma
MAX_SWEPT_ERROR = 0.25  # ... nor is one the fit calibrates to sweep a quarter more or less than its full turns
EXTENDED_ALPHA = 0.01  # the extended model is chosen when its likelihood-ratio test is below this
EXTENDED_FIT_MIN = 1e-3  # ... and when it explains the recording itself (its chi-square's p-value above this)
OFFDIAG_FAIL = 0.05  # ... and worse than this, not identified at all
GN_STEPS = 8  # Gauss-Newton steps before the damped fit takes over
GN_TOL = 1e-3  # ... which has converged when no step is above this share of its parameter's standard error
SPREAD_TOL = 1e-2  # ... and, learning the heading spread, when it moved by less than this share since the step before
_LSQ = {"method": "lm", "xtol": 1e-10, "ftol": 1e-12, "gtol": 1e-10, "x_scale": "jac"}


def calibrate_closure(rec: Recording, stages: Any = None, extended: bool | None = None,
                      heading_prior_deg: float | None = None,
                      k_prior: KPrior | None = None, heading_source: str = "stated") -> CalibrationResult:
    """Calibrate one recording with the closure maximum-likelihood estimator (method "closure").

    stages: a list of Stage, a ProtocolStages, or None to detect them. Every full turn and every
    still segment is used. ``extended`` True adds the three non-orthogonality terms of an upper-triangular K,
    False keeps K diagonal; None (default) adds them where the recording identifies them (each known to
    ``OFFDIAG_WARN``) and the likelihood-ratio test finds them (p < ``EXTENDED_ALPHA``), and says which in
    ``quality["model_choice"]``. Each turn closes onto the pose the accelerometer saw it put back in, with the
    heading it cannot see carried as a prior: of ``heading_prior_deg`` when stated, else the spread the turns about
    horizontal axes show (``calib.estimators.closure.heading``), else ``HEADING_PRIOR_DEG`` (no turn shows it;
    ``calib.estimators.closure.placement``). ``k_prior`` weighs what is known of K with what the recording shows of it
    (identified or not), in the extended model when it knows something of its terms. ``heading_source``: where a
    given heading prior came from ("stated", or "kit": learned from a kit's mean recording), as the result reports it.
    Raises RecordingError for bad input, ProtocolError when a stage is missing,
    CalibrationError when the recording does not determine the parameters (or the terms asked for).
    """
    check_calibration_input(rec)
    stage_list, turns, stills, warnings = _select_stages(rec, stages)
    dt_all = rec.intervals_s

    gyro = rec.gyro[None]
    m, d = windows(gyro, np.array([[[s.start, s.end] for s in turns]]), dt_all[None])
    mean, count, spread = still_statistics(gyro, np.array([[[s.start, s.end] for s in stills]]))
    # a mean over a rest and an angle over a turn scatter as the readings' spread times their colour
    gyro_rests, accel_rests = rest_readings(rec.gyro, rec.accel, [(s.start, s.end) for s in stills])
    sigma = spread * np.sqrt(gyro_rests.colour)
    tilts = measure_tilts(rec, turns, stills, stage_list, accel_rests)
    place = placement_model(tilts, check_heading_prior(heading_prior_deg))
    data = ClosureData(m, d, mean, count, sigma, place.target[None], place.cov[None])
    evidence = None if heading_prior_deg is not None else heading_evidence(tilts, bias_free_angles(data)[0][0])
    evidence = evidence if evidence is not None and evidence.turns else None

    theta0, n_rev, rank = start_values(data, extended=False)
    theta, revolutions = theta0[0], n_rev[0]
    turned = np.ones(3, dtype=bool)
    if rank[0] < 3 or not np.all(np.isfinite(theta0)):
        turned = turned_axes(data)
        if not turned.any():
            raise ProtocolError(
                "no usable turn rotates the device mostly about one of its axes: turn it a full 360 degrees about each "
                "of x, y and z, pausing about 3 s between turns", code="turn_missing", stages=stage_list)
        theta, revolutions = partial_start(data, turned)
        warnings.append(f"{not_turned_text(turned)}: turn the device a full 360 degrees about each axis to calibrate them")
    fit = diagonal = _solve(data, theta, extended=False, not_turned=~turned, evidence=evidence)
    _check_closed(turns, fit, revolutions)  # before the extended terms, which could fold a turn that is not one away
    choice: ModelChoice = {"asked": extended}
    if not turned.all():
        if extended:
            raise CalibrationError(f"the extended model needs turns about every axis; {not_turned_text(turned)}")
        extended = False
        choice["reason"] = "not every axis was turned"
    elif k_prior is not None:
        extended = k_prior.extended
        start = np.concatenate((fit.theta, [np.nan_to_num(k_prior.mean[i, j]) for i, j in OFF_DIAGONAL])) if extended else fit.theta
        fit = _solve(data, start, extended=extended, k_prior=k_prior, evidence=evidence)
        choice["reason"] = "weighed with what was known of K" + (", its terms included" if extended else "")
    elif extended:
        start = np.concatenate((fit.theta, np.zeros(3)))
        _check_identified(data, start)
        fit = _solve(data, start, extended=True, evidence=evidence)
        choice["reason"] = "asked for"
    elif extended is None:
        fit, extended, choice = _choose_model(data, fit, evidence)
    else:
        choice["reason"] = "not asked for"
    if fit is not diagonal:
        _check_closed(turns, fit, revolutions)
    # noise_dps: the readings' own spread, as the other methods report it, not their colour's scale
    result = closure_result(rec, stage_list, turns, stills, data, fit, revolutions, bool(extended), warnings, dt_all, spread[0])
    result.quality["model_choice"] = choice
    heading = fit.heading or HeadingSpread(place.heading_prior_deg, heading_source if heading_prior_deg is not None else "default")
    result.quality["placement"] = placement_report(turns, tilts, (place.tilt_prior_deg, heading.spread_deg), heading_report(heading))
    return result


def _choose_model(data: ClosureData, diagonal: ClosureFit, evidence: HeadingEvidence | None,
                  ) -> tuple[ClosureFit, bool, ModelChoice]:
    """The diagonal fit, or the extended one where the recording identifies its terms and needs them."""
    choice: ModelChoice = {"asked": None}
    start = np.concatenate((diagonal.theta, np.zeros(3)))
    if evidence is not None and diagonal.heading is not None:
        data = evidence.data_with(data, diagonal.heading.spread_deg)
    bound = offdiag_bounds(data, start, diagonal.terms)
    choice["offdiag_bound"] = [float(v) for v in bound]
    if np.any(bound > OFFDIAG_WARN):
        choice["reason"] = (f"the non-orthogonality terms are not identified (standard errors up to {bound.max():.2g}, "
                            f"needs {OFFDIAG_WARN:g}): turns about the sensor axes leave them free")
        return diagonal, False, choice
    try:  # with the diagonal fit's heading spread held: the likelihood ratio compares the terms, not two spreads
        ext = _solve(data, start, extended=True)
        ext = replace(ext, heading=None if diagonal.heading is None else diagonal.heading.padded(9))
    except np.linalg.LinAlgError:  # the extended model's steps left the noise covariance of its rates: it explains nothing
        choice["reason"] = "the extended model could not be fitted (its noise covariance lost its meaning on the way)"
        return diagonal, False, choice
    chi2_ext, dof_ext = float(ext.res @ ext.res), int(data.dof(True)[0])
    lr = float(diagonal.res @ diagonal.res) - chi2_ext
    p = float(chi2_sf(max(lr, 0.0), 3))
    fits = float(chi2_sf(chi2_ext, dof_ext)) if dof_ext > 0 else 1.0
    choice.update({"likelihood_ratio": lr, "p_value": p, "extended_fit_p_value": fits})
    if fits < EXTENDED_FIT_MIN:
        # a misfit the terms only partly absorb (a turn that did not come back, ...) is not non-orthogonality
        choice["reason"] = (f"the extended model does not explain the recording either (chi2/dof = {chi2_ext / dof_ext:.1f}): "
                            "the misfit is something else, see the warnings")
        return diagonal, False, choice
    if p < EXTENDED_ALPHA:
        choice["reason"] = f"identified and significant (p = {p:.2g} < {EXTENDED_ALPHA:g})"
        return ext, True, choice
    choice["reason"] = f"identified but not significant (p = {p:.2g} >= {EXTENDED_ALPHA:g})"
    return diagonal, False, choice


# --------------------------------------------------------------------------- fitting


def _solve(data: ClosureData, theta0: np.ndarray, extended: bool, not_turned: np.ndarray | None = None,
           k_prior: KPrior | None = None, evidence: HeadingEvidence | None = None) -> ClosureFit:
    """The maximum-likelihood fit from ``theta0``: Gauss-Newton (one closure pass a step), or where its steps do not
    settle, least_squares with the turn weights held fixed and re-weighted at its solution until they settle. With
    ``evidence``, the heading spread is learned at each step from the turns that show it (``restricted_spread``).

    ``not_turned`` (3,): axes no
    turn was about, whose scale factors only the hand's wobble informs: each gets the prior N(1, ``NOT_TURNED_K_SD``),
    a working sensor's range, so the turned axes' uncertainty includes what the others could be. ``k_prior``: what is
    known of K's entries (``KPrior``), each known one a prior too.
    """
    held = np.zeros(3, dtype=bool) if not_turned is None else np.asarray(not_turned, dtype=bool)
    index, centre, spread = np.flatnonzero(held), np.ones(int(held.sum())), np.full(int(held.sum()), NOT_TURNED_K_SD)
    if k_prior is not None:
        known, means, stds = k_prior.rows(extended)
        index, centre, spread = np.concatenate((index, known)), np.concatenate((centre, means)), np.concatenate((spread, stds))
    prior_rows = np.zeros((index.size, theta0.shape[0]))
    prior_rows[np.arange(index.size), index] = 1.0 / spread

    def with_prior(res: np.ndarray, th: np.ndarray) -> np.ndarray:
        return np.concatenate((res, (th[index] - centre) / spread))

    fast = _gauss_newton(data, theta0, extended, with_prior, prior_rows, evidence)
    if fast is not None:
        theta, current, nfev, heading = fast
        converged = True
    else:
        heading = None
        if evidence is not None:
            # learning the spread did not settle: the turns pull it apart (a turn far from a full one makes the others'
            # closures look like a sloppy hand at one iterate and not at the next); the default is carried, and said
            data = evidence.data_with(data, HEADING_PRIOR_DEG)
            heading = HeadingSpread(HEADING_PRIOR_DEG, "unsettled", evidence.turns)
        theta, current, nfev, converged = _least_squares(data, theta0, extended, with_prior, prior_rows)
    jacobian = np.vstack((current.J[0], prior_rows))
    return ClosureFit(
        theta=theta,
        res=with_prior(current.res[0], theta),
        fisher=jacobian.T @ jacobian,
        terms=current.terms,
        chol=current.chol[0],
        nfev=nfev,
        converged=converged,
        not_turned=held,
        priors=int(index.size),
        heading=heading,
    )


def _gauss_newton(data: ClosureData, theta: np.ndarray, extended: bool, with_prior: Callable[[np.ndarray, np.ndarray], np.ndarray],
                  prior_rows: np.ndarray, evidence: HeadingEvidence | None = None,
                  ) -> tuple[np.ndarray, System, int, HeadingSpread | None] | None:
    """Gauss-Newton from the linear start with the turn weights recomputed at each iterate: one closure pass a step, and
    the same solution as ``_least_squares`` (both stop where the gradient at the weights of the solution is zero).
    With ``evidence`` the heading spread is learned again at each iterate (the weights follow it without another
    closure pass) and has settled too at the solution, where its and the parameters' uncertainty is found. None when
    its steps do not shrink each time or do not settle within ``GN_STEPS``: the damped fit takes over."""
    last = np.inf
    heading: HeadingSpread | None = None
    for it in range(1, GN_STEPS + 1):
        try:
            current = system(data, theta[None], extended, jacobian=True)
            before, learned_from = heading, (data, current)
            if evidence is not None:
                data, heading = learn_heading(data, current, theta, with_prior, prior_rows, evidence, uncertainty=False)
                current = assemble(data, theta[None], extended, current.terms)
            jac = np.vstack((current.J[0], prior_rows))
            cov = np.linalg.inv(jac.T @ jac)
            step = -cov @ (jac.T @ with_prior(current.res[0], theta))
            std = np.sqrt(np.diag(cov))
        except np.linalg.LinAlgError:  # weights or normal equations lost their meaning on the way
            return None
        size = float(np.max(np.abs(step) / std))
        settled = heading is None or (before is not None and abs(heading.spread_deg - before.spread_deg)
                                      <= SPREAD_TOL * before.spread_deg + 1e-5)
        if not np.isfinite(size) or (size >= last and settled):
            return None
        if size <= GN_TOL and settled:
            if evidence is not None:  # the spread's and the parameters' uncertainty, at the solution only
                _, heading = learn_heading(*learned_from, theta, with_prior, prior_rows, evidence)
            return theta, current, it, heading
        theta, last = theta + step, size
    return None


def _least_squares(data: ClosureData, theta: np.ndarray, extended: bool,
                   with_prior: Callable[[np.ndarray, np.ndarray], np.ndarray],
                   prior_rows: np.ndarray) -> tuple[np.ndarray, System, int, bool]:
    """least_squares (damped) with the turn weights held fixed, re-weighted at its solution until they settle."""
    nfev = 0
    converged = False
    current = system(data, theta[None], extended, jacobian=True)  # weights at theta
    for _ in range(4):
        chol = current.chol
        jac_cache = {theta.tobytes(): current.J[0]}
        res_cache = {theta.tobytes(): current.res[0]}

        def fun(th: np.ndarray, chol=chol, res_cache=res_cache) -> np.ndarray:
            key = th.tobytes()
            if key not in res_cache:
                res_cache.clear()
                res_cache[key] = system(data, th[None], extended, chol=chol, jacobian=False).res[0]
            return with_prior(res_cache[key], th)

        def jac(th: np.ndarray, chol=chol, jac_cache=jac_cache) -> np.ndarray:
            key = th.tobytes()
            if key not in jac_cache:
                jac_cache.clear()
                jac_cache[key] = system(data, th[None], extended, chol=chol, jacobian=True).J[0]
            return np.vstack((jac_cache[key], prior_rows))

        sol = least_squares(fun, theta, jac=jac, **_LSQ)
        nfev += int(sol.nfev)
        if not np.all(np.isfinite(sol.x)):
            raise CalibrationError("the closure fit diverged: check that each turn is one full turn that ends where it began",
                                   code="not_closed")
        theta = sol.x
        converged = bool(sol.success)
        current = system(data, theta[None], extended, jacobian=True)
        # the weights have settled when no closure covariance factor moved by 1 % of its size
        change = np.max(np.abs(current.chol - chol) / np.abs(chol).max(axis=(-2, -1), keepdims=True))
        if change < 1e-2:
            break
    return theta, current, nfev, converged


def _check_closed(turns: list[Stage], fit: ClosureFit, n_rev: np.ndarray) -> None:
    """Raise CalibrationError when a turn is so far from closing that its residual means nothing, or when the fit
    calibrated a turn's rotation away (a full turn sweeps 360 degrees per revolution)."""
    angle = np.degrees(np.linalg.norm(fit.terms_r, axis=1))
    swept = np.linalg.norm(fit.swept, axis=1) / (FULL_TURN_DEG * n_rev)
    worst = int(np.argmax(angle))
    off = int(np.argmax(np.abs(swept - 1.0)))
    if angle[worst] > MAX_CLOSURE_DEG:
        st = turns[worst]
        what = f"ends {angle[worst]:.0f} deg from where it began even after calibration"
    elif abs(swept[off] - 1.0) > MAX_SWEPT_ERROR:
        st = turns[off]
        what = f"would sweep {swept[off] * FULL_TURN_DEG * n_rev[off]:.0f} deg, not {FULL_TURN_DEG * n_rev[off]:.0f}, to close"
    else:
        return
    raise CalibrationError(
        f"the turn about {st.axis} at {st.start_s:.1f}-{st.end_s:.1f} s {what}: it is not a full turn back to the "
        "starting pose. Repeat it, turning exactly 360 degrees and putting the device back in its starting position",
        code="not_closed",
    )


def offdiag_bounds(data: ClosureData, theta: np.ndarray, terms: ClosureTerms | None = None) -> np.ndarray:
    """Cramér-Rao standard errors (3,) of the non-orthogonality terms at ``theta`` (9,); inf where not identified.
    ``terms``: the turns' closure terms at theta already found (a diagonal fit's at its solution), else computed."""
    s = system(data, theta[None], True) if terms is None else assemble(data, theta[None], True, terms)
    F = s.J[0].T @ s.J[0]
    scale = np.sqrt(np.diag(F))
    if np.any(scale <= 0):
        return np.full(3, np.inf)
    Fn = F / np.outer(scale, scale)
    ev = np.linalg.eigvalsh(Fn)
    return np.full(3, np.inf) if ev[0] < 1e-12 * ev[-1] else np.sqrt(np.diag(np.linalg.inv(Fn)))[6:] / scale[6:]


def _check_identified(data: ClosureData, theta: np.ndarray) -> None:
    """Raise CalibrationError when the recording cannot tell the non-orthogonality terms apart."""
    bound = offdiag_bounds(data, theta)
    if np.any(bound > OFFDIAG_FAIL):
        raise CalibrationError(
            "this recording does not determine the non-orthogonality terms of the extended model "
            f"(their standard errors would be {', '.join(f'{v:.2g}' for v in bound)}): turns about fixed "
            "sensor axes leave them free. Add turns about axes between the sensor axes, or use the diagonal model."
        )


# --------------------------------------------------------------------------- input


def _select_stages(rec: Recording, stages: Any) -> tuple[list[Stage], list[Stage], list[Stage], list[str]]:
    """(all stages, turns used, stills used, warnings). Every full turn and still is used."""
    from calib.stages.resolve import check_stages_inside, resolve_stages

    try:
        stage_list = resolve_stages(rec, stages).stages
    except ProtocolError as exc:
        # turns about some axes only: those axes are calibrated, the others said to be undetermined
        if exc.code != "turn_missing" or not any(s.kind == "turn" for s in exc.stages):
            raise
        stage_list = sorted(exc.stages, key=lambda s: s.start)
        check_stages_inside(rec, stage_list)
    warnings: list[str] = []
    turns = []
    for s in stage_list:
        if s.kind != "turn":
            continue
        if FLAG_SATURATED in s.flags:
            warnings.append(
                f"the turn about {s.axis} at {s.start_s:.1f} s reached the gyro's full scale and is not used: turn more slowly"
            )
            continue
        if s.n < 2:
            continue
        if FLAG_COUNTER_GAP in s.flags:
            warnings.append(f"samples were lost during the turn about {s.axis} at {s.start_s:.1f} s; its closure is approximate")
        turns.append(s)
    stills = [s for s in stage_list if s.kind == "still" and s.n >= MIN_STILL_SAMPLES]
    if not turns:
        dropped = [w for w in warnings if "full scale" in w]
        raise ProtocolError(
            "no usable full turn was found: turn the device 360 degrees about each of its axes"
            + (f" ({'; '.join(dropped)})" if dropped else "")
        )
    if not stills:
        raise ProtocolError("no still segment was found: let the device rest about 3 s before, between and after the turns")
    return stage_list, turns, stills, warnings
