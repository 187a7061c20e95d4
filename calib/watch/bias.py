"""The bias of the calibration in force, tested on a recording's rests: at each rest the corrected rate's mean is minus
the bias's change (g = K m + b reads 0 at rest only with the bias in force then), read over pieces of at most 30 s.
It is fitted, per axis, as an offset at the calibration's conditions, a change with the sensor's warmth (against the
temperature channel, or, without one, a warm-up's saturating rise in time), a step at one moment (a drop), and a wander
of the rests' own beyond their means' noise."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from calib.watch.evidence import Evidence
from calib.watch.fits import Z_MOVED, LinearFit, Step, best_step, correlation_inflation, extra_variance, fit
from calib.watch.verdict import ParameterVerdict, Since, judge

MIN_TEMPERATURE_SPREAD_C = 1.0  # the rests' temperatures must spread this much for the bias to be fitted against them
WARMTH_TAUS_S = np.geomspace(60.0, 3600.0, 30)  # a warm-up's time constants tried, without a temperature channel
# without a temperature channel: a bias off the calibration's from the start by no more than this may be the sensor's
# temperature (a clinic against a ward, UNATTRIBUTED_C apart, at this class's largest 0.05 (deg/s)/degC)
UNATTRIBUTED_C = 2.0
UNATTRIBUTED_DPS = 0.05 * UNATTRIBUTED_C


@dataclass(frozen=True)
class BiasFindings:
    """The bias verdicts, and how the bias followed the sensor's warmth: ``temperature_coeff`` +- ``..._std``
    ((deg/s)/degC, with a temperature channel) or ``warmth_change`` +- ``..._std`` (deg/s from the first rest to the
    warmest, without one, with its time constant ``warmth_tau_s``); ``wander_dps`` the rests' own scatter."""

    verdicts: list[ParameterVerdict]
    reference: str
    temperature_coeff: np.ndarray | None = None
    temperature_coeff_std: np.ndarray | None = None
    warmth_change: np.ndarray | None = None
    warmth_change_std: np.ndarray | None = None
    warmth_tau_s: float | None = None
    wander_dps: np.ndarray | None = None

    def to_json(self) -> dict[str, Any]:
        def lst(v: np.ndarray | None) -> list[float] | None:
            return None if v is None else [float(x) for x in v]

        return {"reference": self.reference, "temperature_coeff_dps_per_c": lst(self.temperature_coeff),
                "temperature_coeff_std": lst(self.temperature_coeff_std), "warmth_change_dps": lst(self.warmth_change),
                "warmth_change_std": lst(self.warmth_change_std), "warmth_tau_s": self.warmth_tau_s,
                "wander_dps": lst(self.wander_dps)}


def warm_up(ev: Evidence) -> float | None:
    """Without a temperature channel: the time constant (s) of the saturating rise in time that best explains the
    rests' bias, when it explains them significantly better than none (a wearable warming on the skin), else None."""
    if ev.has_temperature:
        return None
    t = np.array([r.t_mid_s for r in ev.pieces])
    y = -np.array([r.bias_dps for r in ev.pieces])
    var = np.array([r.bias_se_dps for r in ev.pieces]) ** 2
    ones = np.ones((len(t), 1))
    base = sum(fit(ones / np.sqrt(v[:, None]), yy / np.sqrt(v)).chi2 for yy, v in zip(y.T, var.T, strict=True))
    best, best_tau = None, None
    for tau in WARMTH_TAUS_S:
        A = np.column_stack([ones, warmth_in_time(t, warm_up_start(ev), float(tau))])
        chi2 = sum(fit(A / np.sqrt(v[:, None]), yy / np.sqrt(v)).chi2 for yy, v in zip(y.T, var.T, strict=True))
        if best is None or chi2 < best:
            best, best_tau = chi2, float(tau)
    return best_tau if best is not None and base - best >= Z_MOVED**2 else None


def warm_up_start(ev: Evidence) -> float:
    """When a warm-up starts: when the wearable first moved (picked up to be put on), the end of its first rest."""
    return float(ev.rec.t[ev.rests[0].end - 1])


def warmth_in_time(t: np.ndarray, t0: float, tau_s: float) -> np.ndarray:
    """A warm-up's progress at times ``t`` (0 at ``t0``, rising to 1 with time constant ``tau_s``)."""
    return -np.expm1(-np.maximum(np.asarray(t, dtype=float) - t0, 0.0) / tau_s)


def _warmth_regressor(ev: Evidence, temp_ref_c: float | None, tau_s: float | None
                      ) -> tuple[np.ndarray | None, str]:
    """The rests' warmth: temperature less the reference (with a channel whose rests spread enough), else the
    warm-up's progress in time (``tau_s``, from ``warm_up``); with the reference said."""
    if ev.has_temperature:
        temps = np.array([r.temperature_c for r in ev.pieces], dtype=float)
        ref = temps[0] if temp_ref_c is None else temp_ref_c
        said = (f"the calibration's temperature, {ref:.1f} °C" if temp_ref_c is not None
                else f"the first rest's temperature, {ref:.1f} °C (the calibration's is not known)")
        return (temps - ref if np.ptp(temps) >= MIN_TEMPERATURE_SPREAD_C else None), said
    said = "the first rest (no temperature channel: the bias there, before the wearer's warmth)"
    if tau_s is None:
        return None, said
    t = np.array([r.t_mid_s for r in ev.pieces])
    return warmth_in_time(t, warm_up_start(ev), tau_s), said


def _with_a_step(design: np.ndarray, y: np.ndarray, var: np.ndarray, groups: np.ndarray
                 ) -> tuple[Step | None, float, LinearFit]:
    """One axis's rests fitted by ``design``: the step found (or None), the wander's variance and the fit (its
    parameters before the step). The wander is measured with the likeliest step in the model, so that a step is not
    taken for wander; the fit's stds allow for the wander's correlation from one rest to the next."""
    extra = extra_variance(design, y, var)
    w = 1.0 / np.sqrt(var + extra)
    step = best_step(design * w[:, None], y * w, w, groups, always=True)
    if step is not None:
        with_step = np.column_stack([design, groups >= step.at])
        extra_s = extra_variance(with_step, y, var)
        w_s = 1.0 / np.sqrt(var + extra_s)
        step = best_step(design * w_s[:, None], y * w_s, w_s, groups, correlated=True)
        if step is not None:
            extra, w, design = extra_s, w_s, np.column_stack([design, groups >= step.at])
    A, yw = design * w[:, None], y * w
    f = fit(A, yw)
    return step, extra, LinearFit(f.x, f.cov * correlation_inflation(yw - A @ f.x), f.chi2, f.dof)


def _unattributed(p: ParameterVerdict) -> ParameterVerdict:
    """Without a temperature column, a bias unlike the calibration's from the recording's start by no more than a
    temperature difference could make it cannot be told from one: "cannot tell", saying so."""
    if p.verdict != "moved" or p.since is not None or p.change is None or abs(p.change) > UNATTRIBUTED_DPS:
        return p
    return replace(p, verdict="cannot tell", would_tell=f"it differs by {p.change:+.3f} deg/s from the start, as a sensor "
                   f"{UNATTRIBUTED_C:g} °C warmer or colder than at its calibration may: a recording with its temperature "
                   "column would tell")


def bias_findings(ev: Evidence, temp_ref_c: float | None, tau_s: float | None = None) -> BiasFindings:
    """The bias verdicts of ``ev``'s rests (``temp_ref_c``: the calibration's temperature, when known; ``tau_s``:
    without a temperature channel, the warm-up's time constant, ``warm_up``)."""
    tau = tau_s
    warmth, reference = _warmth_regressor(ev, temp_ref_c, tau)
    n = len(ev.pieces)
    design = np.ones((n, 1)) if warmth is None else np.column_stack([np.ones(n), warmth])
    groups = np.arange(n)
    verdicts, coeff, coeff_std, wander = [], [], [], []
    for axis, name in enumerate(("b_x", "b_y", "b_z")):
        y = -np.array([r.bias_dps[axis] for r in ev.pieces])  # at rest the corrected rate is minus the bias's change
        var = np.array([r.bias_se_dps[axis] for r in ev.pieces]) ** 2
        step, extra, f = _with_a_step(design, y, var, groups)
        since = None
        if step is not None:
            since = Since(float(ev.rec.t[ev.pieces[step.at - 1].start] - ev.rec.t[0]),  # a piece may hold the step
                          float(ev.rec.t[ev.pieces[step.at].end - 1] - ev.rec.t[0]))
        verdict = judge(name, float(f.x[0]), float(f.std[0]), step, since, len(ev.rests),
                        "a rest at the calibration's conditions: lay the wearable still for 10 s before it is put on")
        verdicts.append(verdict if ev.has_temperature else _unattributed(verdict))
        wander.append(np.sqrt(extra))
        if warmth is not None:
            coeff.append(float(f.x[1]))
            coeff_std.append(float(f.std[1]))
    if warmth is None:
        return BiasFindings(verdicts, reference, wander_dps=np.array(wander))
    if ev.has_temperature:
        return BiasFindings(verdicts, reference, np.array(coeff), np.array(coeff_std), wander_dps=np.array(wander))
    top = float(np.max(warmth))
    return BiasFindings(verdicts, reference, warmth_change=np.array(coeff) * top, warmth_change_std=np.array(coeff_std) * top,
                        warmth_tau_s=tau, wander_dps=np.array(wander))
