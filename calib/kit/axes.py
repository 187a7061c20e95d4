"""The kit's sensor axes: each wearable's non-orthogonality, from the others', and the kit's common part.

The coupling fixes A_i = K_i^-1 R_i K_ref for every wearable, so each one's upper-triangular K_i follows from the
reference's K_ref (``calib.kit.members``). What it cannot fix is K_ref's own non-orthogonality: changing K_ref by a
small T moves every wearable's tilt (the off-diagonal entries of K D^-1) by one and the same amount, the symmetric part
of T. Turns about the sensor axes do not fix it either (``calib.estimators.closure``: turns about axes between them
would). So:

- where the kit's mean recording identified its non-orthogonality (the closure estimator chose the extended model),
  K_ref is that and every wearable's K follows;
- otherwise the kit fixes the common part by taking its sensors' tilts to average zero. Sensors made one by one have
  non-orthogonalities of their own, so each wearable's is then known to the kit's mean of them, sd / √N, against its
  whole sd when calibrated alone (which cannot see it at all). That common part's uncertainty is the kit's own spread
  of tilts over √N (widened as a t-distribution with 3 (N - 1) degrees of freedom would be);
- the wearables get an upper-triangular K only when their tilts differ beyond their noise (the χ² of the tilts with
  3 (N - 1) degrees of freedom, p below the closure estimator's ``EXTENDED_ALPHA``); otherwise a diagonal K, as alone.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from calib.distributions import chi2_sf
from calib.estimators.closure.estimator import EXTENDED_ALPHA
from calib.json_safe import finite
from calib.kit.clocks import ClockMap
from calib.kit.coupling import LinearMap
from calib.kit.members import UPPER, RefCalibration, member_params, member_tilt, tilt_of
from calib.result import CalibrationResult
from calib.stages.stage import Stage

GAUGE_PASSES = 4  # the common part moves every tilt by the same amount to first order: a few passes settle it


@dataclass(frozen=True, eq=False)
class KitAxes:
    """The kit's axes model: ``full`` (upper-triangular K for every wearable) or diagonal; the reference's K with its
    uncertainty; the χ² of the wearables' tilts against their noise; the spread of the kit's tilts; and why."""

    full: bool
    ref: RefCalibration
    chi2: float
    dof: int
    p_value: float
    spread: float
    reason: str

    def to_dict(self) -> dict[str, Any]:
        return finite({"model": "upper-triangular" if self.full else "diagonal", "chi2": self.chi2, "dof": self.dof,
                       "p_value": self.p_value, "tilt_spread": self.spread, "reason": self.reason})


def reference(mean: CalibrationResult) -> RefCalibration:
    """The kit's mean calibration as the reference's K and b with their uncertainties (NaN where not known)."""
    nan3 = np.full(3, np.nan)

    def entries(K_std: np.ndarray | None, k_spread: np.ndarray | None) -> np.ndarray:
        if K_std is not None:
            return np.asarray(K_std, dtype=float)
        return np.diag(nan3 if k_spread is None else np.asarray(k_spread, dtype=float))

    return RefCalibration(np.asarray(mean.matrix, dtype=float), np.asarray(mean.b, dtype=float),
                          entries(mean.K_std, mean.k_std), nan3 if mean.b_std is None else np.asarray(mean.b_std),
                          entries(mean.K_std, mean.k_bound), nan3 if mean.b_bound is None else np.asarray(mean.b_bound))


def turn_weights(rates: np.ndarray, stages: Sequence[Stage]) -> np.ndarray:
    """(3 axes, 3 tilt entries): how much each tilt entry lengthens the turns about each axis, per unit tilt.

    A calibrated rate g read with K's tilt left out misses Ñ g (Ñ: the tilt's strictly upper matrix), which lengthens a
    turn by ∫ ĝ·Ñ g dt / ∫ |g| dt of its angle: sum over the turn of g_p g_q / |g| per entry (p, q), over sum |g|.
    The turns' closure made up for it in k, so k carries minus that, per axis (the turns about it averaged)."""
    out, count = np.zeros((3, 3)), np.zeros(3)
    for stage in stages:
        if stage.kind != "turn" or stage.axis not in ("x", "y", "z"):
            continue
        g = rates[stage.start:stage.end]
        g = g[np.all(np.isfinite(g), axis=1)]
        speed = np.linalg.norm(g, axis=1)
        if not speed.sum() > 0:
            continue
        moving = speed > 0
        a = "xyz".index(stage.axis)
        out[a] += np.sum(g[moving][:, UPPER[0]] * g[moving][:, UPPER[1]] / speed[moving, None], axis=0) / speed.sum()
        count[a] += 1
    return out / np.maximum(count, 1)[:, None]


def kit_axes(mean: CalibrationResult, maps: Sequence[tuple[LinearMap, ClockMap]], weights: np.ndarray) -> KitAxes:
    """The axes model of a kit whose mean calibration is ``mean``, from each wearable's map and clock (the reference's
    included, as the identity) and the mean's ``turn_weights``: its k were fitted with its tilt as the turns found it
    (none, for a diagonal K), so they are corrected for the common tilt the kit settles on and carry its uncertainty."""
    ref = reference(mean)
    k = np.diag(ref.K)
    turned = tilt_of(ref.K)  # the reference's tilt as the kit's turns found it (0: not identified)
    turned_std = ref.K_std[UPPER] / k[UPPER[1]] if mean.K is not None else np.full(3, np.inf)
    if len(maps) < 2:
        return KitAxes(mean.K is not None, ref, float("nan"), 0, float("nan"), float("nan"), "one wearable left")
    dof = 3 * (len(maps) - 1)
    # every wearable's tilt against the kit's (their weighted mean) and its noise
    params = [member_params(_with_tilt(ref, turned), linear, clock, full=True) for linear, clock in maps]
    tilts = np.array([p.tilt for p in params])
    weight = 1.0 / np.maximum(np.array([p.tilt_bound for p in params]), 1e-12) ** 2
    centre = np.sum(weight * tilts, axis=0) / np.sum(weight, axis=0)
    chi2 = float(np.sum(weight * (tilts - centre) ** 2))
    common = turned - tilts.mean(axis=0)
    for _ in range(GAUGE_PASSES - 1):
        tilts = np.array([member_tilt(_with_tilt(ref, common), linear, clock) for linear, clock in maps])
        common = common - tilts.mean(axis=0)
    p_value = float(chi2_sf(chi2, dof))
    p_text = f"p = {p_value:.2g}" if p_value >= 1e-12 else "p < 1e-12"
    spread = float(np.sqrt(np.sum((tilts - tilts.mean(axis=0)) ** 2) / dof))
    differ = p_value < EXTENDED_ALPHA
    if not differ and mean.K is None:
        return KitAxes(False, ref, chi2, dof, p_value, spread,
                       f"the wearables' axes agree within their noise ({p_text}): diagonal K")
    # the kit's mean tilt taken as zero, known to the kit's spread over sqrt(N) (as a t-distribution's sd), and the
    # turns' finding where they identified it: each weighed by how well it knows the common tilt
    gauge = spread / np.sqrt(len(maps)) * np.sqrt(dof / (dof - 2)) if differ else np.inf
    w_turned, w_gauge = 1.0 / turned_std**2, 1.0 / gauge**2
    tilt = (turned * w_turned + common * w_gauge) / (w_turned + w_gauge)
    tilt_std = 1.0 / np.sqrt(w_turned + w_gauge)
    k = k * (1.0 - weights @ (tilt - turned))
    widen = k * np.sqrt((weights**2) @ np.where(np.isfinite(turned_std), 0.0, tilt_std**2))  # not in the turns' fit
    ref = RefCalibration(np.diag(k), ref.b, np.diag(np.hypot(np.diag(ref.K_std), widen)), ref.b_std,
                         np.diag(np.hypot(np.diag(ref.K_bound), widen)), ref.b_bound)
    how = {(True, False): "the kit's mean non-orthogonality is taken as zero",
           (False, True): "the reference's non-orthogonality is the kit's turns' finding",
           (True, True): "the kit's mean non-orthogonality is weighed between zero and the kit's turns' finding"}
    return KitAxes(True, _with_tilt(ref, tilt, tilt_std), chi2, dof, p_value, spread,
                   ("the wearables' axes are not orthogonal alike" if differ else "the wearables' axes agree within their noise")
                   + f" ({p_text}); "
                   + f"{how[(differ, mean.K is not None)]}, known to {float(np.max(tilt_std)):.1e}")


def _with_tilt(ref: RefCalibration, tilt: np.ndarray, tilt_std: np.ndarray | float = 0.0) -> RefCalibration:
    """``ref`` with K's off-diagonal entries set to the tilt ``tilt``, known to ``tilt_std``."""
    k = np.diag(ref.K)
    K, K_std, K_bound = np.diag(k), np.diag(np.diag(ref.K_std)), np.diag(np.diag(ref.K_bound))
    K[UPPER] = tilt * k[UPPER[1]]
    K_std[UPPER] = K_bound[UPPER] = tilt_std * k[UPPER[1]]
    return RefCalibration(K, ref.b, K_std, ref.b_std, K_bound, ref.b_bound)
