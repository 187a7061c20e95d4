"""Readings clipped at the gyro's full scale: where, and how much rotation the clipping hid.

A plateau is a run of consecutive samples at the full scale on one axis: at 99.5 % of the stated
range, or, with no range stated, a run of identical readings at the largest magnitude the axis
reached (above 100 deg/s) that noise could not produce. Unquantised readings never repeat, so
``MIN_RUN`` of them suffice; a sensor's integer counts do repeat when the noise spans few of them,
so with p the share of the axis's consecutive readings that are equal (highest at rest, so a
cautious estimate of the chance near a rate peak), the run must reach n with p^(n-1) < ``RUN_CHANCE``
(as the stage detector does, ``calib.stages.clip_run_needed``). The hidden rate above the plateau is modelled as a parabolic cap,
m = FS + h (1 - u^2), u in [-1, 1] across the plateau, whose height follows from the slopes the
readings have where they enter and leave it: h = |slope| w / 2 for a half-width w. That height is a
prior for the fit (25 % model uncertainty plus the slopes' noise), the closure decides the rest when
other turns about the same axis pin the scale factor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.recording import Recording
from calib.stages.config import StageConfig, clip_run_needed

# the stage detector's clipping rule, so that the live flag and the diagnosis agree on what is clipped
FULL_SCALE_FRACTION = StageConfig.full_scale_fraction
MIN_RUN = StageConfig.clip_run
RUN_CHANCE = StageConfig.clip_chance  # chance that noise alone repeats a count along a whole run taken as clipped
MIN_CLIP_DPS = StageConfig.clip_min_dps
CAP_MODEL_UNCERTAINTY = 0.25
EDGE_SAMPLES = 4


@dataclass(frozen=True)
class Plateau:
    axis: int
    sign: float
    start: int  # first clipped row
    end: int  # one past the last
    level: float  # |reading| on the plateau, deg/s
    height: float  # prior height of the hidden cap above the plateau (reading units, deg/s)
    height_sd: float
    t0: float  # s since the first sample

    @property
    def n(self) -> int:
        return self.end - self.start


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    d = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=False))


def find_plateaus(rec: Recording) -> list[Plateau]:
    """Plateaus of clipped readings, each with the prior height of the cap it hides."""
    g = rec.gyro
    t = rec.t - rec.t[0]
    fs_stated = rec.meta.gyro_full_scale_dps
    out: list[Plateau] = []
    for ax in range(3):
        a = np.abs(g[:, ax])
        top = float(a.max()) if a.size else 0.0
        if fs_stated:
            mask = a >= FULL_SCALE_FRACTION * float(fs_stated)
            min_run = 1
        else:
            if top < MIN_CLIP_DPS:
                continue
            mask = a >= top
            min_run = _min_run(g[:, ax])
        for s, e in _runs(mask):
            if e - s < min_run:
                continue
            sign = float(np.sign(g[s, ax]))
            level = float(np.abs(g[s:e, ax]).mean())
            h, sd = _cap_height(t, g[:, ax] * sign, s, e, level)
            out.append(Plateau(ax, sign, s, e, level, h, sd, float(t[s])))
    return out


def _min_run(x: np.ndarray) -> int:
    """Shortest run of identical readings at the top that noise would not produce (the stage detector's rule)."""
    p_equal = float(np.mean(x[1:] == x[:-1])) if x.size > 1 else 0.0
    return int(clip_run_needed(p_equal, MIN_RUN, RUN_CHANCE))


def _cap_height(t: np.ndarray, x: np.ndarray, s: int, e: int, level: float) -> tuple[float, float]:
    """Height of the parabolic cap through the plateau's edges with the slopes the readings have there."""
    n = t.size
    dt = float(np.median(np.diff(t))) if n > 1 else 1.0
    half = 0.5 * (float(t[e - 1] - t[s]) + dt)
    slopes, vars_ = [], []
    for lo, hi, sgn in ((max(0, s - EDGE_SAMPLES), s, 1.0), (e, min(n, e + EDGE_SAMPLES), -1.0)):
        if hi - lo < 2:
            continue
        tt, xx = t[lo:hi], x[lo:hi]
        A = np.column_stack((np.ones_like(tt), tt - tt.mean()))
        coef, *_ = np.linalg.lstsq(A, xx, rcond=None)
        resid = xx - A @ coef
        dof = max(1, tt.size - 2)
        s2 = float(resid @ resid) / dof
        var = s2 / max(float(((tt - tt.mean()) ** 2).sum()), 1e-300)
        slope = sgn * coef[1]
        if slope > 0:
            slopes.append(slope)
            vars_.append(var)
    if not slopes:
        return 0.0, max(level, 1.0)
    slope = float(np.mean(slopes))
    slope_sd = float(np.sqrt(np.sum(vars_))) / len(slopes)
    h = slope * half / 2.0
    sd = np.hypot(CAP_MODEL_UNCERTAINTY * h, slope_sd * half / 2.0)
    return h, float(max(sd, 1e-3))


def plateau_caps(n: int, t: np.ndarray, plateaus: list[Plateau]) -> np.ndarray:
    """(n, C) signed cap shapes: reading change per unit of cap height, nonzero on each plateau."""
    caps = np.zeros((n, len(plateaus)))
    tt = t - t[0]
    dt = float(np.median(np.diff(tt))) if n > 1 else 1.0
    for c, p in enumerate(plateaus):
        a, b = p.start, p.end
        centre = 0.5 * (tt[a] + tt[b - 1])
        half = 0.5 * (float(tt[b - 1] - tt[a]) + dt)
        u = (tt[a:b] - centre) / half
        caps[a:b, c] = p.sign * (1.0 - u * u)
    return caps
