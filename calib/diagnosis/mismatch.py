"""What the fitted effects leave unexplained: the statistics where the recording departs from its simulation, what no
catalogued effect explains, which effects could not be told apart, and the recalibration the found effects call
for."""

from __future__ import annotations

import numpy as np

from calib.diagnosis.data import Layout, Problem
from calib.diagnosis.describe import as_floats, rival_evidence, std_of
from calib.diagnosis.extended_fits import ModelState
from calib.diagnosis.features import Features, window_label
from calib.diagnosis.gauss_newton import Fit
from calib.diagnosis.models import Model
from calib.diagnosis.select import DISTINGUISH
from calib.diagnosis.timebase import TimeBase
from calib.stages.stage import AXES


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
        from calib.distributions import norm_sf

        z = tb.clock_e / tb.clock_std
        pz = float(2 * norm_sf(abs(z)))
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
    tests = [rival_evidence(names[0], t) for t in a.get("rival_tests", []) if t["rival"] in names]
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
        "k": as_floats(k), "b": as_floats(b), "k_std": as_floats(sk), "b_std": as_floats(sb),
        "nominal": {"k": as_floats(k0), "b": as_floats(b0), "k_std": as_floats(s0[:3]), "b_std": as_floats(s0[3:6])},
        "shift": {"k": as_floats(k - k0), "b": as_floats(b - b0)},
        "shift_sigma": {"k": as_floats((k - k0) / np.maximum(s0[:3], 1e-12)), "b": as_floats((b - b0) / np.maximum(s0[3:6], 1e-12))},
        "model": list(final.model.effects) + list(final.variance),
        "notes": notes,
    }
    return out
