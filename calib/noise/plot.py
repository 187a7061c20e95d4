"""The Allan deviation plot of a noise report: each axis's curve with its 95 % band, the fitted terms, and the
slopes the noise parameters were read from (-1/2 for the noise density, the floor for bias instability, +1/2 for
the random walk)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from calib.noise.analysis import AxisNoise, NoiseReport
from calib.noise.terms import B_FACTOR
from calib.plots import save_figure

COLOURS = ("C0", "C1", "C2")


def _panel(ax: Any, axes: tuple[AxisNoise, ...], unit: str, scale: float) -> None:
    for colour, a in zip(COLOURS, axes, strict=True):
        c = a.curve
        ax.fill_between(c.tau_s, c.lo95 * scale, c.hi95 * scale, color=colour, alpha=0.18, lw=0)
        ax.loglog(c.tau_s, c.adev * scale, "o", color=colour, ms=3.5, label=f"{a.axis}")
        fine = np.geomspace(c.tau_s[0], c.tau_s[-1], 200)
        ax.loglog(fine, a.fit.adev(fine) * scale, "-", color=colour, lw=1, alpha=0.8)
        if a.density.seen:  # the -1/2 line through N at tau = 1 s
            ax.loglog(fine, a.density.shown * scale / np.sqrt(fine), ":", color=colour, lw=1)
        if a.random_walk.seen:  # the +1/2 line through K at tau = 3 s
            ax.loglog(fine, a.random_walk.shown * scale * np.sqrt(fine / 3.0), "--", color=colour, lw=1)
        if a.bias_instability.seen:
            ax.axhline(a.bias_instability.shown * B_FACTOR * scale, color=colour, lw=0.8, ls="-.", alpha=0.7)
    ax.set_xlabel("averaging time τ (s)")
    ax.set_ylabel(f"Allan deviation ({unit})")
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(title="axis", loc="upper right")


def plot_noise(report: NoiseReport, path: str | Path) -> Path:
    """Save a PNG of the report's Allan deviations (gyroscope, and the accelerometer when recorded)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = 1 if report.accel is None else 2
    fig, axs = plt.subplots(1, panels, figsize=(6.5 * panels, 5.2), constrained_layout=True, squeeze=False)
    _panel(axs[0][0], report.gyro, "deg/h", 3600.0)
    axs[0][0].set_title("gyroscope: dots measured, band 95 %, line fitted\n"
                        "dotted: noise density (slope -1/2), dash-dot: bias instability floor, dashed: random walk (+1/2)",
                        fontsize=9)
    if report.accel is not None:
        _panel(axs[0][1], report.accel, "µg", 1e6)
        axs[0][1].set_title("accelerometer", fontsize=9)
    fig.suptitle(f"{report.source or 'recording'}: {report.duration_s:.0f} s at rest, {report.sample_rate_hz:g} Hz")
    return save_figure(fig, path)
