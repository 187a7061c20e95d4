"""Before/after plots of a calibration (like the paper's Figs. 9 and 10), and the data behind them."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from calib.apply.correction import Correction
from calib.numerics.attitude import cumulative_attitude
from calib.recording import Recording
from calib.result import CalibrationResult
from calib.stages.stage import Stage


def save_figure(fig: Any, path: str | Path, dpi: int = 110) -> Path:
    """Write a matplotlib figure as PNG (its folder created) and release it; the path written."""
    import matplotlib.pyplot as plt

    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return out


def calibration_traces(rec: Recording, result: CalibrationResult, max_points: int = 1500) -> dict[str, Any]:
    """Rate magnitude, pose error and swept angles before (raw readings) and after calibration.

    Returns JSON-ready lists decimated to at most ``max_points`` samples: t (s); rate_before and
    rate_after (deg/s); pose_error_before and pose_error_after, the angle between the attitude
    integrated so far and the start pose (deg: a calibrated device is back at 0 after each full
    turn); swept_before and swept_after, the angle swept so far within each turn about that turn's
    axis (deg, null outside turns: a full turn ends at +-360); and the turn intervals. "Before" integrates the raw readings
    m as they are; "after" integrates K m + b.
    """
    dt = np.diff(rec.t, append=rec.t[-1] + 1.0 / rec.fs)
    before = rec.gyro
    after, _ = Correction.from_result(result).apply(rec.gyro)
    pose_before = np.rad2deg(cumulative_attitude(before, dt).magnitude())
    pose_after = np.rad2deg(cumulative_attitude(after, dt).magnitude())
    swept_before = np.full(len(rec), np.nan)
    swept_after = np.full(len(rec), np.nan)
    for s in result.stages:
        if s.kind == "turn" and s.axis:
            i = "xyz".index(s.axis)
            seg = slice(s.start, s.end)
            rest = -result.b[i] / result.matrix[i, i]  # the raw reading at rest
            swept_before[seg] = np.cumsum((before[seg, i] - rest) * dt[seg])
            swept_after[seg] = np.cumsum(after[seg, i] * dt[seg])
    step = max(1, int(np.ceil(len(rec) / max_points)))
    pick = slice(None, None, step)

    def r(a: np.ndarray, d: int = 3) -> list:
        out = np.round(a[pick], d).astype(object)
        out[np.isnan(a[pick].astype(float))] = None
        return out.tolist()

    return {
        "t": r(rec.t - rec.t[0], 4),
        "rate_before": r(np.linalg.norm(before, axis=1)),
        "rate_after": r(np.linalg.norm(after, axis=1)),
        "pose_error_before": r(pose_before, 2),
        "pose_error_after": r(pose_after, 2),
        "swept_before": r(swept_before, 2),
        "swept_after": r(swept_after, 2),
        "turns": [
            {"axis": s.axis, "start_s": s.start_s - rec.t[0], "end_s": s.end_s - rec.t[0]}
            for s in result.stages
            if s.kind == "turn"
        ],
    }


def plot_calibration(rec: Recording, result: CalibrationResult, path: str | Path) -> Path:
    """Save a PNG: rate magnitude, pose error and swept angles before and after calibration."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tr = calibration_traces(rec, result, max_points=4000)
    t = np.asarray(tr["t"])
    fig, axes = plt.subplots(3, 1, figsize=(10, 9), sharex=True, constrained_layout=True)
    ax = axes[0]
    ax.plot(t, tr["rate_before"], color="0.6", lw=1, label="raw reading |m|")
    ax.plot(t, tr["rate_after"], color="C0", lw=1, label="calibrated |K m + b|")
    ax.set_ylabel("rate magnitude (deg/s)")
    ax.legend(loc="upper right")
    ax = axes[1]
    ax.plot(t, tr["pose_error_before"], color="0.6", lw=1.2, label="raw readings")
    ax.plot(t, tr["pose_error_after"], color="C0", lw=1.2, label="calibrated")
    ax.set_ylabel("angle from start pose (deg)")
    ax.legend(loc="upper left")
    ax = axes[2]
    sb = np.asarray(tr["swept_before"], dtype=float)
    sa = np.asarray(tr["swept_after"], dtype=float)
    ax.plot(t, sb, color="0.6", lw=1.2, ls="--", label="raw readings (bias removed)")
    ax.plot(t, sa, color="C0", lw=1.4, label="calibrated")
    for turn in tr["turns"]:
        ax.text((turn["start_s"] + turn["end_s"]) / 2, 0, turn["axis"], ha="center", va="bottom")
    for level in (-360, 0, 360):
        ax.axhline(level, color="0.8", lw=0.8)
    ax.set_ylabel("angle swept in each turn (deg)")
    ax.legend(loc="upper left")
    for ax in axes:
        for turn in tr["turns"]:
            ax.axvspan(turn["start_s"], turn["end_s"], color="C1", alpha=0.08)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(f"gyrocal calibration ({result.method}): k = {np.round(result.k, 5).tolist()}, "
                 f"b = {np.round(result.b, 4).tolist()} deg/s", fontsize=10)
    return save_figure(fig, path)


STAGE_COLOURS = {"still": "C2", "turn": "C1", "motion": "C3"}


def plot_stages(rec: Recording, stages: list[Stage], path: str | Path, title: str) -> Path:
    """Save a PNG of what the stage detector found in a recording it could not calibrate: the readings per axis,
    with the stills, turns and other motions shaded and labelled, so a user sees which part is missing."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    step = max(1, int(np.ceil(len(rec) / 6000)))
    t = rec.t[::step] - rec.t[0]
    fig, ax = plt.subplots(figsize=(11, 4.5), constrained_layout=True)
    for i, axis in enumerate("xyz"):
        ax.plot(t, rec.gyro[::step, i], lw=0.8, label=f"g{axis} reading")
    top = float(np.max(np.abs(rec.gyro))) or 1.0
    for s in stages:
        a, b = s.start_s - rec.t[0], s.end_s - rec.t[0]
        ax.axvspan(a, b, color=STAGE_COLOURS.get(s.kind, "0.5"), alpha=0.15, lw=0)
        label = s.kind if s.kind != "turn" else f"turn {s.axis} ({s.angle_deg:.0f} deg)" if s.angle_deg is not None else "turn"
        if b - a > 0.02 * (t[-1] - t[0] + 1e-9):
            ax.text((a + b) / 2, top * 1.02, label, ha="center", va="bottom", fontsize=7, rotation=90 if b - a < 3 else 0)
    ax.set_ylim(-top * 1.1, top * 1.35)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("gyro reading (deg/s)")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(title, fontsize=9, wrap=True)
    return save_figure(fig, path)
