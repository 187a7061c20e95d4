"""The kit's sensor axes: each wearable's non-orthogonality, from the others', and the kit's common part.

The coupling fixes A_i = K_i^-1 R_i K_ref for every wearable, so each one's upper-triangular K_i follows from the
reference's K_ref (``calib.kit.members``). What it cannot fix is K_ref's own non-orthogonality: changing K_ref by a
small T moves every wearable's tilt (the off-diagonal entries of K D^-1) by one and the same amount, the symmetric part
of T. Turns about the sensor axes show it only through the hand's wobble, often some entries and not others
(``calib.estimators.closure``). So:

- the wearables get an upper-triangular K only when their tilts differ beyond their noise (the χ² of the tilts with
  3 (N - 1) degrees of freedom, p below the closure estimator's ``EXTENDED_ALPHA``); otherwise a diagonal K, as alone,
  or the extended K the kit's mean recording identified on its own;
- where they differ, the kit takes its sensors' tilts to average zero. Sensors made one by one have
  non-orthogonalities of their own, so each wearable's is then known to the kit's mean of them, sd / √N, against its
  whole sd when calibrated alone (which cannot see it at all). That common part's uncertainty is the kit's own spread
  of tilts over √N (widened as a t-distribution with 3 (N - 1) degrees of freedom would be);
- that zero mean is a prior on the reference's tilt: the kit's mean recording is calibrated again with the closure
  estimator's extended model under it, so what the wobble shows of each entry is weighed in, and K's diagonal is fitted
  with the tilt (a tilt lengthens a turn whose axis is off the sensor's, and the turns' closure would put that in k).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from calib.distributions import chi2_sf
from calib.estimators.closure.estimator import EXTENDED_ALPHA
from calib.estimators.closure.fit import KPrior
from calib.json_safe import finite
from calib.kit.clocks import ClockMap
from calib.kit.coupling import LinearMap
from calib.kit.members import UPPER, RefCalibration, member_params, member_tilt, tilt_of
from calib.result import CalibrationResult

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


Refit = Callable[[KPrior], CalibrationResult]


def kit_axes(mean: CalibrationResult, maps: Sequence[tuple[LinearMap, ClockMap]], refit: Refit | None = None) -> KitAxes:
    """The axes model of a kit whose mean calibration is ``mean``, from each wearable's map and clock (the reference's
    included, as the identity). ``refit`` calibrates the kit's mean recording again with a prior on K's off-diagonal
    terms (the closure estimator's extended model): where the wearables' tilts differ, the kit's zero mean is that
    prior, weighed with what the turns' wobble shows of the reference's tilt, and K's diagonal is fitted with it."""
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
    agree = f"the wearables' axes agree within their noise ({p_text})"
    if not differ:
        how = "diagonal K" if mean.K is None else "the reference's non-orthogonality is the kit's turns' finding"
        return KitAxes(mean.K is not None, ref, chi2, dof, p_value, spread, f"{agree}: {how}")
    # the kit's mean tilt taken as zero, known to the kit's spread over sqrt(N) (as a t-distribution's sd)
    gauge = spread / np.sqrt(len(maps)) * np.sqrt(dof / (dof - 2))
    if refit is not None:
        scale = k[UPPER[1]]  # K's entry above the diagonal is the tilt times the scale factor of its column
        prior_K, prior_std = np.diag(k), np.full((3, 3), np.inf)  # nothing known of K's diagonal but what the turns show
        prior_K[UPPER], prior_std[UPPER] = common * scale, gauge * scale
        ref = reference(refit(KPrior(prior_K, prior_std)))
        k = np.diag(ref.K)
        tilt, tilt_std = tilt_of(ref.K), ref.K_std[UPPER] / k[UPPER[1]]
        how = "the kit's mean non-orthogonality taken as zero, weighed with what the turns' wobble shows of it"
    else:  # a mean calibrated otherwise (its K fitted whole, or diagonal): the two findings weighed, K's diagonal kept
        w_turned, w_gauge = 1.0 / turned_std**2, 1.0 / gauge**2
        tilt = (turned * w_turned + common * w_gauge) / (w_turned + w_gauge)
        tilt_std = 1.0 / np.sqrt(w_turned + w_gauge)
        how = "the kit's mean non-orthogonality taken as zero" + ("" if mean.K is None else ", weighed with the turns' finding")
    return KitAxes(True, _with_tilt(ref, tilt, tilt_std), chi2, dof, p_value, spread,
                   f"the wearables' axes are not orthogonal alike ({p_text}); {how}: known to {float(np.max(tilt_std)):.1e}")


def _with_tilt(ref: RefCalibration, tilt: np.ndarray, tilt_std: np.ndarray | float = 0.0) -> RefCalibration:
    """``ref`` with K's off-diagonal entries set to the tilt ``tilt``, known to ``tilt_std``."""
    k = np.diag(ref.K)
    K, K_std, K_bound = np.diag(k), np.diag(np.diag(ref.K_std)), np.diag(np.diag(ref.K_bound))
    K[UPPER] = tilt * k[UPPER[1]]
    K_std[UPPER] = K_bound[UPPER] = tilt_std * k[UPPER[1]]
    return RefCalibration(K, ref.b, K_std, ref.b_std, K_bound, ref.b_bound)
