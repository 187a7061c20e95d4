"""The scale factors of the calibration in force, tested on a recording's re-orientations: the rotation the corrected
rates integrate to between two rests must carry the end rest's gravity onto the start rest's (two constraints each;
a turn about the vertical is not seen). A relative change dk of the scale factors moves each by a known amount
(``calib.numerics.rotation.rotation_terms``' Jacobian), so dk is a weighted linear fit over the re-orientations, at
the calibration's temperature, with its change per degree where their temperatures spread enough, and a step at one
moment when there is one."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from calib.estimators.multi_position.model import perp_basis, skew
from calib.numerics.rotation import rotation_terms
from calib.numerics.windows import windows
from calib.units import DEG
from calib.watch.bias import warm_up_start, warmth_in_time
from calib.watch.evidence import Evidence
from calib.watch.fits import best_step, fit
from calib.watch.verdict import ParameterVerdict, Since, judge

MIN_TEMPERATURE_SPREAD_C = 4.0  # the re-orientations' temperatures must spread this much for dk to be fitted against them
EXERCISED_DEG = 30.0  # a re-orientation exercises an axis when a scale change of 1 moves its gravity by this (deg)
# the gravity directions' error beyond their noise (the accelerometer's own calibration, a rest's settling) is
# measured from the re-orientations' scatter; at least this much is assumed
DIRECTION_FLOOR_RAD = 0.005 * DEG
MIN_EXERCISED = 4  # re-orientations about an axis below which its k cannot be told for want of them
WOULD_TELL = {
    0: "about its x axis with x level: between two rests, turn it a quarter turn about x while x lies "
       "horizontal (roll it from lying on the back onto a side)",
    1: "about its y axis with y level: between two rests, turn it a quarter turn about y while y lies "
       "horizontal (from standing to sitting)",
    2: "about its z axis with z level: between two rests, lie it on its side (z horizontal) and turn it "
       "a quarter turn about z",
}


@dataclass(frozen=True)
class ScaleFindings:
    """The k verdicts, the re-orientations used, how many exercised each axis, and dk's change per degree when
    fitted (``temperature_coeff`` +- ``..._std``, per degC)."""

    verdicts: list[ParameterVerdict]
    used: int
    exercised: list[int]
    temperature_coeff: np.ndarray | None = None
    temperature_coeff_std: np.ndarray | None = None

    def to_json(self) -> dict[str, Any]:
        def lst(v: np.ndarray | None) -> list[float] | None:
            return None if v is None else [float(x) for x in v]

        return {"reorientations_used": self.used, "exercised": dict(zip("xyz", self.exercised, strict=True)),
                "temperature_coeff_per_c": lst(self.temperature_coeff), "temperature_coeff_std": lst(self.temperature_coeff_std)}


def _cannot(ev: Evidence, why: str) -> ScaleFindings:
    return ScaleFindings([ParameterVerdict(f"k_{a}", "cannot tell", None, None, would_tell=why) for a in "xyz"], 0, [0, 0, 0])


def scale_findings(ev: Evidence, temp_ref_c: float | None, warm_up_tau_s: float | None = None) -> ScaleFindings:
    """The k verdicts of ``ev``'s re-orientations (``temp_ref_c``: the calibration's temperature, when known;
    ``warm_up_tau_s``: without a temperature channel, the warm-up's time constant the rests showed, ``bias.warm_up``:
    k may follow the warmth as the bias does)."""
    rec, cor, reos = ev.rec, ev.correction, ev.reorientations
    if rec.accel is None or any(r.gravity is None for r in ev.rests):
        return _cannot(ev, "the recording has no accelerometer: record it with the gyroscope, so that gravity measures "
                           "the re-orientations")
    if len(reos) < 2:
        return _cannot(ev, "fewer than two re-orientations between rests: rest it, turn it a quarter turn, rest again")
    m = rec.gyro
    if cor.G is not None:
        _, a_cal = cor.apply(rec.gyro, rec.accel)
        m = m - (rec.accel if a_cal is None else a_cal) @ cor.G.T
    bounds = np.array([[[r.start, r.end] for r in reos]])
    mw, dw = windows(m[None], bounds, rec.intervals_s[None])
    B = len(reos)
    before, after = [ev.rests[r.before] for r in reos], [ev.rests[r.after] for r in reos]
    # the bias during each motion: between the end of the rest before and the start of the rest after (a warming
    # sensor's bias moves through a long rest: its mean is its middle's)
    local_bias = np.array([(a.edges_dps[1] + b.edges_dps[0]) / 2 for a, b in zip(before, after, strict=True)])
    K = np.broadcast_to(cor.K, (B, 3, 3)).copy()
    terms = rotation_terms(mw, dw, K, cor.b - local_bias, np.broadcast_to(ev.noise_dps, (B, 3)).copy())
    u_s = np.array([a.gravity for a in before], dtype=float)
    u_e = np.array([b.gravity for b in after], dtype=float)
    u_s /= np.linalg.norm(u_s, axis=1, keepdims=True)
    u_e /= np.linalg.norm(u_e, axis=1, keepdims=True)
    basis = perp_basis(u_s)  # (B, 3, 2)
    carried = np.einsum("bij,bj->bi", terms.C, u_e)
    rho = np.einsum("bji,bj->bi", basis, carried - u_s)  # (B, 2) rad
    P = -np.einsum("bji,bjk->bik", basis, skew(carried))  # (B, 2, 3)
    D = np.einsum("bail,il->bai", terms.dK, cor.K)  # rotation per unit relative change of each axis's scale
    A = np.einsum("bij,bjk->bik", P, D)  # (B, 2, 3)
    # the noise of each constraint: the readings' through the motion, the local bias's error over its duration, and
    # the two gravity directions'
    wander = np.array([(a.edges_se_dps[1] ** 2 + b.edges_se_dps[0] ** 2) / 4 for a, b in zip(before, after, strict=True)])
    dur = np.array([r.duration_s for r in reos])
    phi_cov = terms.noise + np.einsum("bi,ij->bij", wander * (dur[:, None] * DEG) ** 2, np.eye(3))
    direction = np.array([_direction_var(ev, r.before) + _direction_var(ev, r.after) for r in reos])
    cov = np.einsum("bij,bjk,blk->bil", P, phi_cov, P) + direction[:, None, None] * np.eye(2)
    temps = np.array([np.nan if r.temperature_c is None else r.temperature_c for r in reos])
    with_temp = bool(np.isfinite(temps).all() and np.ptp(temps) >= MIN_TEMPERATURE_SPREAD_C)
    warmth = None  # each re-orientation's warmth: its temperature less the reference, or its warm-up's progress
    if with_temp:
        warmth = temps - (temp_ref_c if temp_ref_c is not None else float(ev.rests[0].temperature_c or temps[0]))
    elif warm_up_tau_s is not None:
        mid = np.array([(rec.t[r.start] + rec.t[r.end - 1]) / 2 for r in reos])
        warmth = warmth_in_time(mid, warm_up_start(ev), warm_up_tau_s)

    groups = np.repeat(np.arange(B), 2)

    def whitened(floor: float, steps: dict[int, int] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The whitened rows with ``floor`` added: each k's column, its warmth's, and a step column for each axis in
        ``steps`` (axis: the first re-orientation after it)."""
        L = np.linalg.cholesky(cov + floor * np.eye(2))
        Aw = np.linalg.solve(L, A).reshape(2 * B, 3)
        yw = -np.linalg.solve(L, rho[..., None])[..., 0].reshape(2 * B)
        design = Aw if warmth is None else np.column_stack([Aw, Aw * np.repeat(warmth, 2)[:, None]])
        for axis, at in (steps or {}).items():
            design = np.column_stack([design, Aw[:, axis] * (groups >= at)])
        return Aw, design, yw

    Aw, design, yw = whitened(_floor(whitened, DIRECTION_FLOOR_RAD**2))
    found = {i: st for i in range(3) if (st := best_step(design, yw, Aw[:, i], groups)) is not None}
    if found:  # the steps in the model, so that their misfit is not taken for the constraints' scatter
        at = {i: st.at for i, st in found.items()}
        Aw, design, yw = whitened(_floor(lambda fl: whitened(fl, at), DIRECTION_FLOOR_RAD**2), at)
    f = fit(design, yw)
    exercised = [int(np.sum(np.linalg.norm(A[:, :, i], axis=1) >= EXERCISED_DEG * DEG)) for i in range(3)]
    verdicts = []
    first_step = design.shape[1] - len(found)
    for i, name in enumerate(("k_x", "k_y", "k_z")):
        step, since = found.get(i), None
        if step is not None:
            col = first_step + list(found).index(i)
            step = replace(step, size=float(f.x[col]), std=float(f.std[col]))
            since = Since(float(rec.t[reos[step.at - 1].end - 1] - rec.t[0]), float(rec.t[reos[step.at].start] - rec.t[0]))
        tell = (f"too few re-orientations ({exercised[i]} of at least {MIN_EXERCISED}) {WOULD_TELL[i]}" if exercised[i] < MIN_EXERCISED else
            f"the {exercised[i]} re-orientations about {name[-1]} disagree beyond their noise: more of them, each between "
            "two rests of a few seconds, would tell")
        verdicts.append(judge(name, float(f.x[i]), float(f.std[i]), step, since, exercised[i], tell))
    if not with_temp:  # (without a temperature channel the warm-up's share is not a coefficient per degree)
        return ScaleFindings(verdicts, B, exercised)
    return ScaleFindings(verdicts, B, exercised, f.x[3:6].copy(), f.std[3:6].copy())


def _floor(whitened: Any, least: float) -> float:
    """The variance (rad^2) to add to each constraint so that the fit's chi-square per degree of freedom is 1, at
    least ``least``."""

    def excess(floor: float) -> float:
        _, design, yw = whitened(floor)
        f = fit(design, yw)
        return f.chi2 - f.dof

    if excess(least) <= 0.0:
        return least
    lo, hi = least, max(least * 4, (1.0 * DEG) ** 2)
    while excess(hi) > 0.0 and hi < 1.0:
        hi *= 4.0
    for _ in range(24):  # to a few percent of the floor: its effect on the stds is smaller still
        mid = (lo * hi) ** 0.5 if lo > 0.0 else 0.5 * hi
        lo, hi = (mid, hi) if excess(mid) > 0.0 else (lo, mid)
    return hi


def _direction_var(ev: Evidence, rest: int) -> float:
    """The variance (rad^2) of a rest's gravity direction from the accelerometer's noise over its samples."""
    r = ev.rests[rest]
    assert ev.rec.accel is not None
    sd = float(np.mean(ev.rec.accel[r.start:r.end].std(axis=0)))
    return sd**2 / max(r.end - r.start, 1)
