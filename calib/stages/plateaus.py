"""Readings clipped at the gyro's full scale: where, and how much rotation the clipping hid (the caps' shapes the
diagnosis fits are in calib.diagnosis.saturation).

A plateau is a run of consecutive samples at the full scale on one axis: at 99.5 % of the stated
range, or, with no range stated, a run of identical readings at the largest magnitude the axis
reached (above 100 deg/s) that noise could not produce. Unquantised readings never repeat, so
``MIN_RUN`` of them suffice; a sensor's integer counts do repeat when the noise spans few of them,
so with p the share of the axis's consecutive readings that are equal (highest at rest, so a
cautious estimate of the chance near a rate peak), the run must reach n with p^(n-1) < ``RUN_CHANCE``
(as the stage detector does, ``calib.stages.clip_run_needed``), unless that magnitude is a ceiling (two runs
share it, or it is a common full scale): then ``MIN_RUN`` suffice. The hidden rate above the plateau is modelled as a parabolic cap,
m = FS + h (1 - u^2), u in [-1, 1] across the plateau, whose height follows from the slopes the
readings have where they enter and leave it: h = |slope| w / 2 for a half-width w. That height is a
prior for the fit (25 % model uncertainty plus the slopes' noise), the closure decides the rest when
other turns about the same axis pin the scale factor.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calib.recording import Recording
from calib.stages.config import StageConfig, clip_run_needed
from calib.stages.stage import FLAG_SATURATED, Stage

# the stage detector's clipping rule, so that the live flag and the diagnosis agree on what is clipped
FULL_SCALE_FRACTION = StageConfig.full_scale_fraction
MIN_RUN = StageConfig.clip_run
RUN_CHANCE = StageConfig.clip_chance  # chance that noise alone repeats a count along a whole run taken as clipped
MIN_CLIP_DPS = StageConfig.clip_min_dps
CAP_MODEL_UNCERTAINTY = 0.25
EDGE_SAMPLES = 4
# gyro ranges MEMS parts offer, deg/s: InvenSense MPU/ICM 250-2000, ST LSM9DS1 245/500/2000 and LSM6 125-4000,
# Bosch BMI160 125-2000 (their datasheets' full-scale tables)
COMMON_FULL_SCALES_DPS = (125.0, 245.0, 250.0, 500.0, 1000.0, 2000.0, 4000.0)


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
    """The runs [start, end) of True in ``mask`` (few: found from where it holds)."""
    at = np.flatnonzero(mask)
    if not at.size:
        return []
    cut = np.flatnonzero(np.diff(at) != 1) + 1
    starts, ends = at[np.concatenate(([0], cut))], at[np.concatenate((cut - 1, [at.size - 1]))] + 1
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


def find_plateaus(rec: Recording) -> list[Plateau]:
    """Plateaus of clipped readings, each with the prior height of the cap it hides."""
    g = rec.gyro
    t = rec.t - rec.t[0]
    fs_stated = rec.meta.gyro_full_scale_dps
    by_axis = np.ascontiguousarray(g.T)  # (3, n): each axis' readings in a row
    magnitude = np.abs(by_axis)
    tops = magnitude.max(axis=1) if g.size else np.zeros(3)
    # a range stated may be the format's, not the sensor's (imu_tk's counts span 300 deg/s)
    ceilings = _ceilings(magnitude, tops)
    out: list[Plateau] = []
    for ax in range(3):
        a, top = magnitude[ax], float(tops[ax])
        if ax in ceilings:
            mask, min_run = a >= top, MIN_RUN
        elif fs_stated:
            mask = a >= FULL_SCALE_FRACTION * float(fs_stated)
            min_run = 1
        else:
            if top < MIN_CLIP_DPS:
                continue
            mask = a >= top
            min_run = _min_run(by_axis[ax])
        for s, e in _runs(mask):
            if e - s < min_run:
                continue
            sign = float(np.sign(g[s, ax]))
            level = float(np.abs(g[s:e, ax]).mean())
            h, sd = _cap_height(t, g[:, ax] * sign, s, e, level)
            out.append(Plateau(ax, sign, s, e, level, h, sd, float(t[s])))
    return out


def clipped_spans(rec: Recording, spans: list[tuple[int, int]]) -> list[bool]:
    """For each span of samples [start, end), whether a plateau begins in it."""
    plateaus = find_plateaus(rec)
    return [any(lo <= p.start < hi for p in plateaus) for lo, hi in spans]


def flag_clipped_turns(rec: Recording, stages: list[Stage]) -> list[Stage]:
    """``stages`` with every turn that holds a plateau flagged saturated (the estimators then leave it out and say
    so); the stage detector flags only what its streaming rule sees, and with no range stated a short plateau at a
    ceiling escapes it."""
    plateaus = find_plateaus(rec)
    if not plateaus:
        return stages
    out = []
    for st in stages:
        if st.kind == "turn" and FLAG_SATURATED not in st.flags and any(st.start <= p.start < st.end for p in plateaus):
            st = replace(st, flags=(*st.flags, FLAG_SATURATED))
        out.append(st)
    return out


def _ceilings(magnitude: np.ndarray, tops: np.ndarray) -> set[int]:
    """The axes whose largest reading is a ceiling, with no range stated: a value that two runs of MIN_RUN identical
    readings or more reach (on one axis or several; two motions' peaks do not land on the same count by chance), or a
    common full scale. Their plateaus need only MIN_RUN readings: a turn clipped for a tenth of a second leaves runs
    of 10-20, shorter than the noise rule asks of quantised readings (13-15 on imucal's session)."""
    reached: list[tuple[int, float, int]] = []  # (axis, its largest |reading|, its runs of MIN_RUN or more at it)
    for ax, a in enumerate(magnitude):
        if not a.size or (top := float(tops[ax])) < MIN_CLIP_DPS:
            continue
        runs = sum(1 for s, e in _runs(a >= top) if e - s >= MIN_RUN)
        reached.append((ax, top, runs))
    out = set()
    for ax, top, runs in reached:
        shared = sum(r for _, level, r in reached if abs(level - top) <= 1e-9 * top) >= 2
        common = any(abs(top - fs) <= (1.0 - FULL_SCALE_FRACTION) * fs for fs in COMMON_FULL_SCALES_DPS)
        if runs and (shared or common):
            out.add(ax)
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
