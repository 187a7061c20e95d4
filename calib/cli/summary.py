"""A calibration result for people: what ``gyrocal calibrate`` and ``gyrocal demo`` print without ``--json``."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from calib import __version__


def fmt_vec(v: Sequence[float] | np.ndarray | None, digits: int = 5) -> str:
    if v is None:
        return "-"
    return "[" + ", ".join(f"{x:+.{digits}f}" for x in v) + "]"


def result_summary(result: Any, source: str) -> str:
    """A readable summary of a CalibrationResult."""
    d = result.to_dict()
    lines = [f"gyrocal {__version__} — calibration of {source} (method: {d['method']})", ""]
    proto = (d.get("quality") or {}).get("protocol")
    if proto:
        lines += [f"Protocol found: {proto['found']['name']} — {proto['found']['summary']}; used: {proto['used']}"
                  + (f" ({proto['sections']} labelled sections)" if proto.get("sections") else ""), ""]
    lines.append("Stages found:")
    residuals = _gravity_residuals_by_motion(d.get("quality") or {})
    for s in d["stages"]:
        extra = ""
        if s["kind"] == "turn":
            extra = f"  about {s['axis']}, {s['angle_deg']:+.1f} deg"
        if s["kind"] != "still":
            extra += next((residuals.pop(span) for span in list(residuals)
                           if span[0] - 1e-6 <= s["start_s"] and s["end_s"] <= span[1] + 1e-6), "")
        flags = f"  [{', '.join(s['flags'])}]" if s["flags"] else ""
        lines.append(f"  {s['kind']:<7} {s['start_s']:8.2f} – {s['end_s']:8.2f} s{extra}{flags}")
    lines.append("")
    unc = d.get("uncertainty") or {}
    bound = d.get("bound") or {}
    undetermined = (d.get("quality") or {}).get("undetermined_axes") or []
    if undetermined:
        lines += [f"INCOMPLETE: no usable full turn about {' and '.join(undetermined)}, so "
                  f"{'its' if len(undetermined) == 1 else 'their'} k and b are not determined; the other axes are "
                  "calibrated below", ""]
    lines.append("Model g = K m + b  (g true rate, m reading, deg/s)")
    lines.append(f"{'':4}{'value':>12}{'std':>12}{'bound':>12}")
    for name, key, digits in (("k", "k", 6), ("b", "b", 4)):
        for i, axis in enumerate("xyz"):
            std = unc.get(key)
            bnd = bound.get(key)
            unit = "" if key == "k" else " deg/s"
            if axis in undetermined:
                lines.append(f"{name}_{axis:<2}{'not determined':>14}")
                continue
            lines.append(
                f"{name}_{axis:<2}{d[key][i]:>12.{digits}f}"
                f"{(f'{std[i]:.2g}' if std else '-'):>12}"
                f"{(f'{bnd[i]:.2g}' if bnd else '-'):>12}{unit}"
            )
    lines.extend(_interval_lines(result, undetermined))
    if d.get("K") is not None:
        lines.append("Full calibration matrix K:")
        lines.extend("  " + fmt_vec(row, 6) for row in d["K"])
    if d.get("G") is not None:
        lines.append("g-sensitivity G of g = K (m - G a) + b, (deg/s)/g (row: gyro axis, column: acceleration axis):")
        lines.extend("  " + fmt_vec(row, 4) for row in d["G"])
    q = d.get("quality") or {}
    lines.extend(_g_sensitivity_lines(q.get("g_sensitivity")))
    lines.extend(_placement_lines(q.get("placement")))
    lines.extend(_constraint_lines(q))
    if d.get("noise_dps"):
        lines.append(f"Noise (from the stills): {fmt_vec(d['noise_dps'], 4)} deg/s")
    if q:
        shown = (f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in q.items() if not isinstance(v, (dict, list)))
        lines.append("Quality: " + ", ".join(shown))
    for w in d.get("warnings") or []:
        lines.append(f"warning: {w}")
    return "\n".join(lines)


def _interval_lines(result: Any, undetermined: list[str]) -> list[str]:
    """The 95 % intervals that are not value ± 1.96 std: where a variance rests on a spread learned from few turns."""
    intervals = result.interval(0.95)
    if intervals is None:
        return []
    lines = []
    for name, values, std, dofs, digits in (("k", intervals[0], result.k_std, result.k_dof, 6),
                                            ("b", intervals[1], result.b_std, result.b_dof, 4)):
        for i, axis in enumerate("xyz"):
            lo, hi = values[i]
            normal = 1.96 * std[i] if std is not None else np.nan
            few = dofs is not None and np.isfinite(dofs[i]) and dofs[i] <= 30
            if axis in undetermined or not (few or abs((hi - lo) / 2 / normal - 1) > 0.1):
                continue
            shape = f"a Student-t of {dofs[i]:.1f} degrees of freedom" if few else "about normal"
            lines.append(f"{name}_{axis}: 95 % interval {lo:.{digits}f} to {hi:.{digits}f} ({shape}, "
                         f"{(hi - lo) / 2 / normal:.2f}x the ± 1.96 std: its uncertainty rests on the hand's heading "
                         "spread, learned from few turns)")
    return lines


def _placement_lines(placement: dict[str, Any] | None) -> list[str]:
    """Where the hand put the device back after each turn (closure)."""
    if not placement:
        return []
    if not placement.get("measured_by"):
        return [f"Placement after each turn: {placement.get('note')}"]
    each = [f"{t['axis'] or '?'} {t['tilt_deg']:.2f} ± {t['tilt_std_deg']:.2f} deg" for t in placement.get("turns") or []
            if t.get("tilt_deg") is not None]
    if not each:
        return []
    return [f"Placement after each turn (tilt, from the accelerometer, taken into account): {', '.join(each)}; "
            f"{placement.get('note')}"]


def _g_sensitivity_lines(test: dict[str, Any] | None) -> list[str]:
    """What the g-sensitivity test found, and the fit without it (multi-position)."""
    if not test:
        return []
    without = test.get("without") or {}
    rms = without.get("gravity_residual_rms_deg")
    before = f"; without it: Birge ratio {without['birge_ratio']:.2f}"
    if rms is not None:
        before += f", gravity residuals {rms:.3f} deg rms"
    return [f"g-sensitivity {'fitted' if test.get('fitted') else 'not fitted'}: {test.get('reason', '')}" + before]


def _gravity_residuals_by_motion(q: dict[str, Any]) -> dict[tuple[float, float], str]:
    """Each re-orientation's gravity residual after calibration (multi-position), as printed beside its motion,
    keyed by the motion's [start, end] s."""
    spans, deg, z = q.get("gravity_motions_s") or [], q.get("gravity_residual_deg") or [], q.get("gravity_z") or []
    return {(a, b): f"  gravity residual {r:.3f} deg (chi-square {zz**2:.1f} for 2)"
            for (a, b), r, zz in zip(spans, deg, z, strict=False)}


def _constraint_lines(q: dict[str, Any]) -> list[str]:
    """Each kind of constraint's chi-square against what noise explains, the accelerometer's noise floor, the gyro's
    noise while moving and the rests still settling (multi-position)."""
    out = []
    fits = q.get("constraint_fit") or {}
    if fits:
        shown = (f"{kind.replace('_', ' ')} {f['chi2']:.1f} / {f['expected']:.1f} = {f['ratio']:.2f} (p {f['p_value']:.2g})"
                 for kind, f in fits.items() if f.get("ratio") is not None)
        out.append("Chi-square per constraint / what the noise explains: " + "; ".join(shown))
    floor = q.get("accelerometer_floor") or {}
    if floor.get("measured"):
        axes = ", ".join(f"{axis} {mg:.3f}" if mg > 0 else f"{axis} none" for axis, mg in zip("xyz", floor["per_axis_mg"], strict=True))
        out.append(f"Accelerometer noise floor (rest means' scatter beyond white noise, measured on rest {floor['rest']} "
                   f"over {floor['tau_s']:.1f} s spans): {axes} mg")
    elif floor:
        from calib.noise.accel_floor import MIN_SPANS

        out.append(f"Accelerometer noise floor: not measured (no rest holds {MIN_SPANS} spans of a typical rest's length); "
                   "rest means counted as white noise only")
    moving = q.get("gyro_motion_noise") or {}
    if moving.get("measured"):
        lo, hi = moving["band_hz"]
        axes = ", ".join(f"{axis} {r:.2f}" + ("" if c != 1.0 else " (within chance, not counted)")
                         for axis, r, c in zip("xyz", moving["variance_ratio"], moving["counted"], strict=True))
        out.append(f"Gyroscope noise while moving over at rest (variance, {lo:.0f}-{hi:.0f} Hz): {axes}")
    elif moving:
        out.append(f"Gyroscope noise while moving: not measured ({moving.get('reason') or 'no reason given'}); "
                   "motions counted with the rests' noise")
    settling = q.get("settling") or {}
    if settling.get("drift_deg"):
        out.append(f"Rests still settling (counted in their noise): {len(settling['rests_counted'])} of "
                   f"{len(settling['drift_deg'])}, largest drift {settling['largest_deg']:.3f} deg")
    return out
