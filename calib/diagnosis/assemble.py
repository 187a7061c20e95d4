"""The diagnosis as a result: its parts put together in the order the report reads (mismatches, named effects
with their evidence and fit, what is unexplained or not identifiable, the recalibration), JSON-ready."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calib.diagnosis.data import build_problem, make_layout
from calib.diagnosis.features import Features
from calib.diagnosis.fitting import fit_nominal
from calib.diagnosis.select import ADVICE, ALPHA
from calib.distributions import chi2_sf
from calib.errors import GyrocalError
from calib.recording import Recording
from calib.stages.detector import detect_stages

CLOCK_MIN = 5e-4  # a clock rate error below this (500 ppm) is within what the host's own clock may show
CLOCK_Z = 6.0


@dataclass
class Diagnosis:
    """What the recording shows beyond the nominal model, and how much modelling it helps.

    ``to_dict()`` gives the JSON of ``gyrocal diagnose --json``: mismatches (where the recording
    departs from its simulation), effects (named, fitted, ranked), unexplained (clear departures no
    catalogued effect explains), plus not_identifiable, recalibration, nominal and simulation_check.
    """

    mismatches: list[dict]
    effects: list[dict]
    unexplained: list[dict]
    not_identifiable: list[dict]
    recalibration: dict | None
    nominal: dict
    simulation_check: dict
    info: dict
    details: dict = field(default_factory=dict, repr=False)  # arrays for the report; not in to_dict()

    @property
    def names(self) -> list[str]:
        """The named effects, most important first."""
        return [e["name"] for e in self.effects]

    def to_dict(self) -> dict[str, Any]:
        return _jsonable({
            "mismatches": self.mismatches,
            "effects": self.effects,
            "unexplained": self.unexplained,
            "not_identifiable": self.not_identifiable,
            "recalibration": self.recalibration,
            "nominal": self.nominal,
            "simulation_check": self.simulation_check,
            "info": self.info,
        })


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if np.isfinite(v) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def _raw_deviance(raw: Recording | None) -> float:
    """Nominal deviance of the recording as delivered, each reading held until the next one arrives."""
    if raw is None:
        return float("nan")
    try:
        st = detect_stages(raw)
        lay = make_layout(raw, st)
        p = build_problem(lay, raw.gyro[None], None if raw.accel is None else raw.accel[None])
        return float(fit_nominal(p).deviance[0])
    except GyrocalError:
        return float("nan")


def assemble_diagnosis(rec, raw, host_t, prob, layout, tb, plateaus, fit0, base, base_fit, cap_fit, steps, ambiguities, final, feats,
              boot_feats,
              boot_feats_after, p_before, p_after, tests, not_ident, specs, alpha, n_boot, duration) -> Diagnosis:
    from calib.diagnosis.describe import describe_effect
    from calib.diagnosis.mismatch import describe_ambiguity, describe_unexplained, mismatch_rows, recalibration

    effects: list[dict] = []
    # deterministic evidence first: the time base and the gyro range
    if base.clipped:
        effects.append(describe_effect("saturation", prob, layout, fit0=fit0, base=base, base_fit=base_fit,
                                       cap_fit=cap_fit, plateaus=plateaus))
    if tb.lost > 0 and tb.index_source is not None:
        effects.append(describe_effect("sample_loss", prob, layout, tb=tb, duration=duration,
                                       closure_fit=(_raw_deviance(raw), float(fit0.deviance[0]))))
    clock = tb.clock_e is not None and abs(tb.clock_e) > CLOCK_MIN and abs(tb.clock_e) > CLOCK_Z * (tb.clock_std or 0.0)
    if clock:
        effects.append(describe_effect("clock_error", prob, layout, tb=tb))
    for step, _ in steps:
        # each effect's size as the final model has it: an effect taken later can change an earlier one's (a drift tried
        # on top of a wander gives the wander back its own correlation time)
        effects.append(describe_effect(step.name, prob, layout, step=step, state=final, tests=tests, duration=duration))
    effects.sort(key=lambda e: -_importance(e))

    not_identifiable = [{"name": n, "reason": reason} for n, reason in not_ident.items()
                        if n not in [e["name"] for e in effects]]
    if tb.index_source is None and rec.seq is None:
        not_identifiable.append({"name": "sample_loss", "reason": "not identifiable with this recording: the timestamps "
                                 "are not the device's own and there is no sample counter; " + ADVICE["sample_loss"]})
    elif tb.lost == 0 and not rec.loss_visible:
        not_identifiable.append({"name": "sample_loss", "reason": (
            "not identifiable with this recording: it has no sample counter and its times are an exact even grid, which "
            "a file writer's own numbering gives as well as a device's clock: samples lost on the way would leave no "
            "gap, and a run lost inside a turn shortens it, raising its scale factor by the share lost (a turn about the "
            "vertical gives the accelerometer nothing to check it by); " + ADVICE["sample_loss"])})
    if tb.clock_e is None:
        not_identifiable.append({"name": "clock_error", "reason": "not identifiable with this recording: the device "
                                 "clock only scales every turn like the scale factors do; " + ADVICE["clock_error"]})

    mismatches = mismatch_rows(feats, boot_feats, p_before, alpha_features(feats), tb, plateaus, rec)
    unexplained = describe_unexplained(prob, layout, final, feats, boot_feats_after if steps else boot_feats,
                                       p_after if steps else p_before, alpha_features(feats), bool(effects),
                                       bool(ambiguities))
    for a in ambiguities:
        unexplained.insert(0, describe_ambiguity(a))
    recal = recalibration(prob, fit0, final, effects, tb, plateaus, base, cap_fit)
    d0 = float(fit0.deviance[0])
    nominal = {"k": fit0.psi[0, :3], "b": fit0.psi[0, 3:6], "deviance": d0, "dof": float(fit0.dof[0]),
               "p_value": float(chi2_sf(d0, max(fit0.dof[0], 1.0))), "turns": layout.J, "stills": layout.S}
    worst_before = float(np.min(p_before)) if p_before.size else 1.0
    sim = {
        "features": int(p_before.size),
        "threshold": alpha_features(feats),
        "outside_before": int(np.sum(p_before < alpha_features(feats))),
        "worst_p_before": worst_before,
        "outside_after": None if p_after is None else int(np.sum(p_after < alpha_features(feats))),
        "worst_p_after": None if p_after is None else float(np.min(p_after)),
    }
    info = {
        "n_boot": n_boot,
        "samples": len(rec),
        "duration_s": duration,
        "sample_rate_hz": rec.fs,
        "gyro_full_scale_dps": rec.meta.gyro_full_scale_dps,  # the stated range clipping is judged against (None: unknown)
        "channels": {"accelerometer": rec.accel is not None, "sample_counter": rec.seq is not None,
                     "temperature": rec.temp is not None},
        "tests": {v["name"] if k != "bias_drift_temp" else "bias_drift (temperature)": {
            "statistic": v["statistic"], "p_value": v["p_value"], "threshold": alpha,
            "typical_noncentrality": v["noncentrality"]} for k, v in tests.items()},
        "timebase": tb.summary(),
    }
    details = {"features": feats, "boot": boot_feats, "boot_after": boot_feats_after, "p_before": p_before,
               "p_after": p_after, "prob": prob, "fit0": fit0, "final": final, "plateaus": plateaus, "tb": tb,
               "layout": layout, "rec": rec, "raw": raw if raw is not None else rec, "steps": steps,
               "host_t": host_t}
    return Diagnosis(mismatches, effects, unexplained, not_identifiable, recal, nominal, sim, info, details)


def alpha_features(feats: Features) -> float:
    return ALPHA / max(1, len(feats.names))


def _importance(e: dict) -> float:
    f = e.get("fit") or {}
    b, a = f.get("before"), f.get("after")
    if b is None or a is None:
        return 0.0
    return float(b - a)
