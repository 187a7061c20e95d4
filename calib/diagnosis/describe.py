"""Plain-language rows of a diagnosis: effects with their parameters, mismatches, what is left unexplained."""

from __future__ import annotations

import numpy as np

from calib.diagnosis.data import Layout, Problem
from calib.diagnosis.engine import Fit, covariance
from calib.diagnosis.features import Features, window_label
from calib.diagnosis.models import R0_DPS, Model
from calib.diagnosis.saturation import Plateau
from calib.diagnosis.select import DISTINGUISH, ModelState, Step
from calib.diagnosis.timebase import TimeBase
from calib.stages.stage import AXES


def std_of(fit: Fit) -> np.ndarray:
    """Standard errors of a fit's parameters, scaled up by the Birge ratio when the fit is poor."""
    cov = covariance(fit.fisher)[0]
    birge = np.sqrt(max(1.0, float(fit.deviance[0]) / max(float(fit.dof[0]), 1.0)))
    return np.sqrt(np.abs(np.diag(cov))) * birge


def _vec(v) -> list[float]:
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
        params = {"rate_dps_per_s": _vec(psi[s]), "change_dps": _vec(psi[s] * duration)}
        unc = {"rate_dps_per_s": _vec(std[s]), "change_dps": _vec(std[s] * duration)}
        i = _strongest(psi[s], std[s])
        summary = (f"the zero-rate output moves steadily over the recording, by {psi[s][i] * duration:+.3f} deg/s on "
                   f"{AXES[i]} in {duration:.0f} s (the still means line up in time)")
        simulate = f"bias_drift={_fmt(psi[s])}"
    elif step.key == "bias_drift_temp":
        s = sl["bias_drift_temp"]
        params = {"temp_coeff_dps_per_c": _vec(psi[s])}
        unc = {"temp_coeff_dps_per_c": _vec(std[s])}
        i = _strongest(psi[s], std[s])
        summary = (f"the zero-rate output follows the sensor temperature: {psi[s][i]:+.4f} (deg/s)/degC on {AXES[i]}")
        rise = float(np.ptp(prob.block.temp[0])) if prob.block.temp is not None else 0.0
        simulate = f"bias_drift=0:{_fmt(psi[s])}:{rise:.3g}"
    elif step.key == "axis_misalignment":
        s = sl["axis_misalignment"]
        params = {"off_diagonal": _vec(psi[s])}
        unc = {"off_diagonal": _vec(std[s])}
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
        params = {"asymmetry": _vec(psi[s])}
        unc = {"asymmetry": _vec(std[s])}
        i = _strongest(psi[s], std[s])
        summary = (f"the scale factor differs between directions: {2 * psi[s][i] * 100:+.2f} % between positive and "
                   f"negative turns about {AXES[i]}")
        simulate = f"scale_asymmetry={_fmt(psi[s])}"
    elif step.key == "scale_nonlinearity":
        s = sl["scale_nonlinearity"]
        params = {"coeff": _vec(psi[s]), "ref_rate_dps": R0_DPS}
        unc = {"coeff": _vec(std[s])}
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
        evidence["rivals"] = [_rival_evidence(name_out, t) for t in step.rivals]
    return {"name": name_out, "parameters": params, "uncertainty": unc,
            "fit": {"before": float(step.before.deviance[0]), "after": float(step.after.deviance[0])}, "evidence": evidence}


def _rival_evidence(name: str, t: dict) -> dict:
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
    from calib.diagnosis.select import refit

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
    turns = [f"turn about {layout.turns[j].axis} at {layout.turns[j].start_s:.1f} s" for j in base.clipped]
    return {
        "name": "saturation",
        "parameters": {"full_scale_dps": levels[0] if len(levels) == 1 else levels, "clipped_samples": n_clip,
                       "plateaus": len(plateaus), "clipped_turns": len(base.clipped), "hidden_rotation_deg": hidden},
        "uncertainty": {"hidden_rotation_deg": hidden_sd},
        "fit": {"before": float(fit0.deviance[0]), "after": float(base_fit.deviance[0])},
        "evidence": {
            "summary": (f"{n_clip} readings sit at the gyro's full scale (+-{levels[0]:g} deg/s) in {len(base.clipped)} turn(s): "
                        f"the hand turned faster than the range, and the clipped part hides about {sum(hidden):.0f} deg of "
                        "rotation; the clipped turns are left out of the calibration"),
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


def _range(b: np.ndarray) -> list[float]:
    b = b[np.isfinite(b)]
    if b.size == 0:
        return [float("nan"), float("nan")]
    return [float(np.quantile(b, 0.025)), float(np.quantile(b, 0.975))]


def mismatch_rows(feats: Features, boot: np.ndarray, p: np.ndarray, alpha: float, tb: TimeBase, plateaus, rec) -> list[dict]:
    rows = []
    for i in np.argsort(p):
        if p[i] >= alpha:
            break
        rows.append({"where": feats.where[i], "statistic": feats.names[i], "observed": float(feats.values[0, i]),
                     "simulated_range": _range(boot[:, i]), "p_value": float(p[i])})
    if plateaus:
        rows.insert(0, {"where": ", ".join(sorted({f"{AXES[q.axis]} axis" for q in plateaus})),
                        "statistic": "samples_at_full_scale", "observed": int(sum(q.n for q in plateaus)),
                        "simulated_range": [0, 0], "p_value": 0.0})
    if tb.lost:
        rows.insert(0, {"where": f"{len(tb.gaps)} gaps, first at {tb.gaps[0][2]:.2f} s", "statistic": "lost_samples",
                        "observed": tb.lost, "simulated_range": [0, 0], "p_value": 0.0})
    if tb.clock_e is not None and tb.clock_std:
        from scipy.stats import norm

        z = tb.clock_e / tb.clock_std
        pz = float(2 * norm.sf(abs(z)))
        if pz < alpha and abs(tb.clock_e) > 5e-4:
            rows.insert(0, {"where": "whole recording: device clock against host receive times",
                            "statistic": "clock_rate_error", "observed": tb.clock_e,
                            "simulated_range": [-1.96 * tb.clock_std, 1.96 * tb.clock_std], "p_value": pz})
    return rows


def describe_unexplained(prob: Problem, layout: Layout, final: ModelState, feats: Features, boot: np.ndarray,
                         p: np.ndarray, alpha: float, have_effects: bool, ambiguous: bool = False) -> list[dict]:
    """Features still outside what the (extended) simulation produces, grouped and described by shape."""
    out: list[dict] = []
    off = np.flatnonzero(p < alpha)
    if off.size == 0:
        return out
    groups: dict[str, list[int]] = {}
    for i in off:
        groups.setdefault(feats.groups[i], []).append(int(i))
    values = feats.values[0]
    for group, idx in groups.items():
        worst = min(idx, key=lambda i: p[i])
        entry = {"where": [feats.where[i] for i in idx], "statistic": group, "observed": [float(values[i]) for i in idx],
                 "simulated_range": [_range(boot[:, i]) for i in idx], "p_value": float(p[worst])}
        entry["description"] = _shape(group, idx, feats, layout, values, have_effects, ambiguous)
        out.append(entry)
    return out


def describe_ambiguity(a: dict) -> dict:
    """A mismatch that two or more catalogued effects explain about equally well."""
    names = a["candidates"]
    advice = "; ".join(f"{DISTINGUISH[n]} ({n})" for n in names if n in DISTINGUISH)
    base = f" on top of {', '.join(a['base'])}" if a["base"] else ""
    tests = [_rival_evidence(names[0], t) for t in a.get("rival_tests", []) if t["rival"] in names]
    simulated = (" Simulations of each could not set either aside: " + "; ".join(t["summary"] for t in tests) + "."
                 if tests else "")
    out = {
        "where": "the recording as a whole",
        "statistic": "ambiguous",
        "candidates": names,
        "information_criterion": a["ic"],
        "description": (f"a mismatch{base} that {' and '.join(names)} explain about equally well (information criteria "
                        f"within {4:g} of each other): this recording cannot tell which; to tell them apart: {advice}."
                        f"{simulated}"),
    }
    if tests:
        out["rival_tests"] = tests
    return out


def _shape(group: str, idx: list[int], feats: Features, layout: Layout, values: np.ndarray, have_effects: bool,
           ambiguous: bool = False) -> str:
    if ambiguous:
        prefix = "not resolved (see the ambiguity above): "
    else:
        prefix = "after the named effects are modelled, " if have_effects else "no catalogued effect explains it: "
    if group == "still_rate":
        # per axis, the still means against time: steady trend or wander?
        names = [feats.names[i] for i in idx]
        axes = sorted({n[-1] for n in names})
        parts = []
        for a in axes:
            sel = [i for i, n in enumerate(feats.names) if n.startswith("still_rate_") and n.endswith(a)]
            y = values[sel]
            tmid = np.array([0.5 * (layout.stills[int(feats.names[i].split("_")[2])].start_s +
                                    layout.stills[int(feats.names[i].split("_")[2])].end_s) for i in sel])
            if y.size >= 3:
                A = np.column_stack((np.ones_like(tmid), tmid))
                coef, *_ = np.linalg.lstsq(A, y, rcond=None)
                resid = y - A @ coef
                linear = float(np.sum(resid**2)) < 0.25 * float(np.sum((y - y.mean()) ** 2))
                shape = (f"a steady trend of {coef[1]:+.2g} deg/s per s" if linear else
                         f"changes from still to still without a steady trend (spread {np.ptp(y):.3f} deg/s)")
            else:
                shape = f"differs between stills by {np.ptp(y):.3f} deg/s"
            parts.append(f"axis {a}: {shape}")
        return prefix + "the zero-rate output at rest " + "; ".join(parts)
    if group == "closure":
        turns = sorted({int(feats.names[i].split("_")[1]) for i in idx})
        parts = []
        for j in turns:
            v = np.array([values[feats.names.index(f"closure_{j}_{a}")] for a in AXES])
            i = int(np.argmax(np.abs(v)))
            parts.append(f"the {window_label(layout, j)} ends "
                         f"{np.linalg.norm(v):.3f} deg from where it began, mostly about {AXES[i]}")
        return prefix + "; ".join(parts)
    if group == "whiteness":
        parts = [f"{feats.where[i]}: the readings vary {values[i]:.1f} times more over 0.5 s blocks than white noise"
                 for i in idx]
        return prefix + "; ".join(parts) + " (slow wander or vibration during the rest)"
    if group == "tilt":
        parts = [f"{feats.where[i]}: {values[i]:.3f} deg" for i in idx]
        return prefix + "the device came back tilted: " + "; ".join(parts)
    if group == "gravity":
        parts = [f"{window_label(layout, int(feats.names[i].split('_')[1]))}: {values[i]:.3f} deg" for i in idx]
        return prefix + ("the gravity the calibrated gyro carries across these re-orientations misses the accelerometer's: "
                         + "; ".join(parts))
    return prefix + group


def recalibration(prob: Problem, fit0: Fit, final: ModelState, effects: list[dict], tb: TimeBase, plateaus,
                  base: Model, cap_fit) -> dict | None:
    """The calibration with the found effects modelled, and how far it moved from the nominal one."""
    if not effects:
        return None
    k0, b0 = fit0.psi[0, :3], fit0.psi[0, 3:6]
    s0 = std_of(fit0)
    psi = final.fit.psi[0]
    s1 = std_of(final.fit)
    k, b = psi[:3].copy(), psi[3:6].copy()
    sk, sb = s1[:3].copy(), s1[3:6].copy()
    notes = []
    names = [e["name"] for e in effects]
    if "clock_error" in names and tb.device_stamps:
        e = float(tb.clock_e or 0.0)
        k, b = k * (1 + e), b * (1 + e)
        notes.append(f"the device's time stamps run {e * 100:+.2f} % off true time: k and b are corrected by (1 + e)")
    if "sample_loss" in names:
        notes.append("lost samples are put back by cubic interpolation at their sample numbers (counter or timestamps)")
    if base.clipped:
        for ax in range(3):
            turns_ax = [j for j, s in enumerate(prob.layout.turns) if s.axis == AXES[ax]]
            clipped = [j for j in base.clipped if prob.layout.turns[j].axis == AXES[ax]]
            if not clipped:
                continue
            if set(turns_ax) <= set(clipped):
                notes.append(f"every turn about {AXES[ax]} was clipped at the gyro's full scale: k_{AXES[ax]} = {k[ax]:.4f} "
                             f"comes from plateaus rebuilt from their edges (+-{sk[ax]:.2g}); repeat the turn about "
                             f"{AXES[ax]} more slowly for a trustworthy value")
            else:
                notes.append(f"{len(clipped)} clipped turn(s) about {AXES[ax]} are left out; the unclipped ones fix k_{AXES[ax]}")
    out = {
        "k": _vec(k), "b": _vec(b), "k_std": _vec(sk), "b_std": _vec(sb),
        "nominal": {"k": _vec(k0), "b": _vec(b0), "k_std": _vec(s0[:3]), "b_std": _vec(s0[3:6])},
        "shift": {"k": _vec(k - k0), "b": _vec(b - b0)},
        "shift_sigma": {"k": _vec((k - k0) / np.maximum(s0[:3], 1e-12)), "b": _vec((b - b0) / np.maximum(s0[3:6], 1e-12))},
        "model": list(final.model.effects) + list(final.variance),
        "notes": notes,
    }
    return out
