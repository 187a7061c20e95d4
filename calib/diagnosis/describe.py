"""Plain-language rows of a diagnosis: effects with their parameters, mismatches, what is left unexplained."""

from __future__ import annotations

import numpy as np

from calib.diagnosis.data import Layout, Problem
from calib.diagnosis.extended_fits import ModelState
from calib.diagnosis.gauss_newton import Fit, covariance
from calib.diagnosis.models import R0_DPS
from calib.diagnosis.select import Step
from calib.diagnosis.timebase import TimeBase
from calib.stages.plateaus import Plateau
from calib.stages.stage import AXES


def std_of(fit: Fit) -> np.ndarray:
    """Standard errors of a fit's parameters, scaled up by the Birge ratio when the fit is poor."""
    cov = covariance(fit.fisher)[0]
    birge = np.sqrt(max(1.0, float(fit.deviance[0]) / max(float(fit.dof[0]), 1.0)))
    return np.sqrt(np.abs(np.diag(cov))) * birge


def as_floats(v) -> list[float]:
    return [float(x) for x in np.ravel(v)]


def _fmt(v, digits=3) -> str:
    return ",".join(f"{x:.{digits}g}" for x in np.ravel(v))


def _strongest(v: np.ndarray, sd: np.ndarray) -> int:
    """Index of the parameter furthest from 0 in standard errors."""
    z = np.abs(v) / np.where(np.isfinite(sd) & (sd > 0), sd, np.inf)
    return int(np.argmax(z)) if np.any(z > 0) else int(np.argmax(np.abs(v)))


def describe_effect(name: str, prob: Problem, layout: Layout, **kw) -> dict:
    if name == "saturation":
        return _saturation(prob, layout, kw["fit0"], kw["base"], kw["base_fit"], kw["cap_fit"], kw["plateaus"])
    if name == "sample_loss":
        return _loss(kw["tb"], layout, kw["duration"], kw.get("closure_fit"))
    if name == "clock_error":
        return _clock(kw["tb"])
    step: Step = kw["step"]
    state: ModelState = kw["state"]
    tests = kw["tests"]
    test = tests.get(step.key, {})
    fit = state.fit
    std = std_of(fit)
    psi = fit.psi[0]
    sl = state.model.slices
    params: dict = {}
    unc: dict = {}
    summary = ""
    simulate = ""
    duration = kw.get("duration", 1.0)
    if step.key == "bias_drift":
        s = sl["bias_drift"]
        params = {"rate_dps_per_s": as_floats(psi[s]), "change_dps": as_floats(psi[s] * duration)}
        unc = {"rate_dps_per_s": as_floats(std[s]), "change_dps": as_floats(std[s] * duration)}
        i = _strongest(psi[s], std[s])
        summary = (f"the zero-rate output moves steadily over the recording, by {psi[s][i] * duration:+.3f} deg/s on "
                   f"{AXES[i]} in {duration:.0f} s (the still means line up in time)")
        simulate = f"bias_drift={_fmt(psi[s])}"
    elif step.key == "bias_drift_temp":
        s = sl["bias_drift_temp"]
        params = {"temp_coeff_dps_per_c": as_floats(psi[s])}
        unc = {"temp_coeff_dps_per_c": as_floats(std[s])}
        i = _strongest(psi[s], std[s])
        summary = (f"the zero-rate output follows the sensor temperature: {psi[s][i]:+.4f} (deg/s)/degC on {AXES[i]}")
        rise = float(np.ptp(prob.block.temp[0])) if prob.block.temp is not None else 0.0
        simulate = f"bias_drift=0:{_fmt(psi[s])}:{rise:.3g}"
    elif step.key == "axis_misalignment":
        s = sl["axis_misalignment"]
        params = {"off_diagonal": as_floats(psi[s])}
        unc = {"off_diagonal": as_floats(std[s])}
        i = _strongest(psi[s], std[s])
        summary = (f"the sensor axes are not orthogonal: K_{['xy', 'xz', 'yz'][i]} = {psi[s][i]:+.4f} (a turn about one "
                   "axis leaks into another's reading)")
        simulate = f"axis_misalignment={_fmt(psi[s])}"
    elif step.key == "g_sensitivity":
        s = sl["g_sensitivity"]
        G = psi[s].reshape(3, 3)
        params = {"matrix_dps_per_g": G.tolist()}
        unc = {"matrix_dps_per_g": std[s].reshape(3, 3).tolist()}
        i, j = (int(x) for x in np.unravel_index(_strongest(psi[s], std[s]), (3, 3)))
        poses = prob.block.a[0] if prob.block.a is not None else np.zeros((1, 3))
        spread = float(np.ptp(poses / np.linalg.norm(poses, axis=1, keepdims=True), axis=0).max()) if poses.size else 0.0
        where = ("the zero-rate output follows the direction of gravity from one rest pose to the next"
                 if spread > 0.5 else "the turns close according to how gravity turned during each of them")
        assumed = "" if prob.tilt is not None else " (no accelerometer: gravity taken along z at the start, the device resting flat)"
        summary = f"the gyro reads acceleration: {G[i, j]:+.4f} (deg/s)/g on {AXES[i]} per g along {AXES[j]}; {where}{assumed}"
        simulate = f"g_sensitivity={_fmt(G)}"
    elif step.key == "scale_asymmetry":
        s = sl["scale_asymmetry"]
        params = {"asymmetry": as_floats(psi[s])}
        unc = {"asymmetry": as_floats(std[s])}
        i = _strongest(psi[s], std[s])
        summary = (f"the scale factor differs between directions: {2 * psi[s][i] * 100:+.2f} % between positive and "
                   f"negative turns about {AXES[i]}")
        simulate = f"scale_asymmetry={_fmt(psi[s])}"
    elif step.key == "scale_nonlinearity":
        s = sl["scale_nonlinearity"]
        params = {"coeff": as_floats(psi[s]), "ref_rate_dps": R0_DPS}
        unc = {"coeff": as_floats(std[s])}
        i = _strongest(psi[s], std[s])
        summary = (f"the scale factor changes with speed: {psi[s][i] * 100:+.2f} % at {R0_DPS:.0f} deg/s about "
                   f"{AXES[i]} (fast and slow turns disagree)")
        simulate = f"scale_nonlinearity={_fmt(psi[s])}"
    elif step.key == "placement_error":
        s = sl["placement_error"]
        rho = psi[s].reshape(-1, 3)
        srho = std[s].reshape(-1, 3)
        rms = float(np.sqrt(np.mean(rho**2)))
        params = {"rotation_deg": rho.tolist(), "std_deg": rms}
        unc = {"rotation_deg": srho.tolist()}
        j = int(np.argmax(np.linalg.norm(rho, axis=1)))
        summary = (f"the device was not put back exactly after each turn: up to {np.linalg.norm(rho[j]):.2f} deg after the "
                   f"turn about {layout.turns[j].axis} at {layout.turns[j].start_s:.1f} s (the accelerometer sees the tilt)")
        simulate = f"placement_error={rms:.3g}"
    elif step.key == "placement_var":
        tp = state.variance["placement_var"]
        params = {"std_deg": tp}
        unc = {"std_deg": _profile_sd(prob, state, "placement_var")}
        summary = (f"the turns do not close to within noise, by about {tp:.2f} deg per axis with no pattern another effect "
                   "explains: the device was not put back exactly (record the accelerometer to confirm)")
        simulate = f"placement_error={tp:.3g}"
    elif step.key == "bias_instability":
        sigma, tau = state.variance["bias_instability"]
        params = {"sigma_dps": sigma, "tau_s": tau}
        unc = {"sigma_dps": _profile_sd(prob, state, "bias_instability")}
        summary = (f"the zero-rate output wanders like correlated noise (std {sigma:.4f} deg/s, correlation time "
                   f"about {tau:.0f} s): the still means differ by more than white noise allows, without a steady trend")
        simulate = f"bias_instability={sigma:.3g},{tau:.3g}"
    name_out = "placement_error" if step.key == "placement_var" else ("bias_drift" if step.key == "bias_drift_temp" else step.key)
    evidence = {
        "summary": summary,
        "statistic": test.get("statistic", step.statistic),
        "p_value": step.p_value,
        "information_criterion": {"before": step.ic[0], "after": step.ic[1]},
        "held_out": {"before": step.cv[0], "after": step.cv[1]},
        "simulate": simulate,
    }
    if step.rivals:
        evidence["rivals"] = [rival_evidence(name_out, t) for t in step.rivals]
    return {"name": name_out, "parameters": params, "uncertainty": unc,
            "fit": {"before": float(step.before.deviance[0]), "after": float(step.after.deviance[0])}, "evidence": evidence}


def rival_evidence(name: str, t: dict) -> dict:
    """Cox's test against a rival explanation, with a sentence saying what the simulations showed."""
    d = t["criterion_difference"]
    rival = t["rival"]
    said = [f"{name} fits {'better' if d < 0 else 'worse'} than {rival} by {abs(d):.1f} in the information criterion"]
    if t["p_value_rival"] is not None:
        said.append(f"{t['as_far_rival']} of {t['simulations_rival']} simulations of {rival} give a difference at least "
                    f"this favourable to {name}")
    if t["p_value_named"] is not None:
        said.append(f"{t['as_far_named']} of {t['simulations_named']} simulations of {name} give one at least this "
                    f"favourable to {rival}")
    return dict(t, summary=", ".join(said))


def _profile_sd(prob: Problem, state: ModelState, which: str) -> float:
    """Standard error of a variance parameter from the curvature of the profile deviance (log scale)."""
    from calib.diagnosis.extended_fits import refit

    base = dict(state.variance)
    v = base[which]
    x = v[0] if isinstance(v, tuple) else v

    def dev(scale: float) -> float:
        var = dict(base)
        var[which] = (x * scale, v[1]) if isinstance(v, tuple) else x * scale
        return float(refit(prob, state.model, state.fit.psi, state.priors, var, max_iter=1).deviance[0])

    h = 0.1
    d0, dp, dm = dev(1.0), dev(np.exp(h)), dev(np.exp(-h))
    curv = (dp - 2 * d0 + dm) / h**2  # of -2 log L in log(x)
    if curv <= 0:
        return float("inf")
    return float(x * np.sqrt(2.0 / curv))


def _saturation(prob, layout, fit0, base, base_fit, cap_fit, plateaus: list[Plateau]) -> dict:
    k = np.abs(base_fit.psi[0, :3])
    dt = float(np.median(layout.dt))
    hidden, hidden_sd, where = [], [], []
    for p in plateaus:
        half = 0.5 * p.n * dt
        area = 4.0 / 3.0 * half  # of the parabolic cap per unit height
        hidden.append(float(k[p.axis] * p.height * area))
        hidden_sd.append(float(k[p.axis] * p.height_sd * area))
        where.append(f"{AXES[p.axis]} axis at {p.t0:.2f} s, {p.n} samples")
    levels = sorted({round(p.level, 3) for p in plateaus})
    n_clip = int(sum(p.n for p in plateaus))
    turns = [(f"re-orientation at {layout.turns[j].start_s:.1f} s" if layout.moves[j] else
              f"turn about {layout.turns[j].axis} at {layout.turns[j].start_s:.1f} s") for j in base.clipped]
    what = "re-orientation(s)" if layout.moves[list(base.clipped)].all() else "turn(s)"

    return {
        "name": "saturation",
        "parameters": {"full_scale_dps": levels[0] if len(levels) == 1 else levels, "clipped_samples": n_clip,
                       "plateaus": len(plateaus), "clipped_turns": len(base.clipped), "hidden_rotation_deg": hidden},
        "uncertainty": {"hidden_rotation_deg": hidden_sd},
        "fit": {"before": float(fit0.deviance[0]), "after": float(base_fit.deviance[0])},
        "evidence": {
            "summary": (f"{n_clip} readings sit at the gyro's full scale (+-{levels[0]:g} deg/s) in {len(base.clipped)} {what}: "
                        f"the hand turned faster than the range, and the clipped part hides about {sum(hidden):.0f} deg of "
                        f"rotation; the clipped {what} are left out of the calibration"),
            "where": where + turns,
            "simulate": f"saturation={levels[0]:g}",
        },
    }


def _loss(tb: TimeBase, layout: Layout, duration: float, closure_fit: tuple[float, float] | None) -> dict:
    before, after = tb.loss_fit or (0.0, 0.0)
    if closure_fit is not None and all(np.isfinite(closure_fit)):
        # the time base, plus the turns and rests with each reading held over a gap against the gaps bridged
        before, after = before + closure_fit[0], after + closure_fit[1]
    total = int(tb.index[-1] - tb.index[0] + 1)
    frac = tb.lost / max(total, 1)
    where = [f"{g[1]} sample(s) missing at {g[2]:.2f} s" for g in tb.gaps[:20]]
    burst = max(1, round(tb.lost / max(len(tb.gaps), 1)))
    src = "the sample counter" if tb.index_source == "counter" else "the device timestamps"
    bridged = "the lost readings are put back by cubic interpolation at their sample numbers"
    return {
        "name": "sample_loss",
        "parameters": {"lost_samples": tb.lost, "gaps": len(tb.gaps), "fraction": frac},
        "uncertainty": {"lost_samples": 0, "fraction": 0.0},
        "fit": {"before": before, "after": after},
        "evidence": {"summary": f"{tb.lost} samples ({100 * frac:.2f} %) are missing in {len(tb.gaps)} gaps, seen in {src}; {bridged}",
                     "where": where, "simulate": f"sample_loss={len(tb.gaps) / max(total, 1):.3g},{burst}"},
    }


def _clock(tb: TimeBase) -> dict:
    before, after = tb.clock_fit or (0.0, 0.0)
    e = float(tb.clock_e or 0.0)
    return {
        "name": "clock_error",
        "parameters": {"error": e},
        "uncertainty": {"error": float(tb.clock_std or 0.0)},
        "fit": {"before": before, "after": after},
        "evidence": {"summary": (f"the device's sample clock runs {abs(e) * 100:.2f} % {'fast' if e > 0 else 'slow'} against "
                                 "the host's receive times: every turn reads that much too far, which the scale factors absorb"),
                     "simulate": f"clock_error={e:.4g}"},
    }


# --------------------------------------------------------------------------- mismatches and what is left


