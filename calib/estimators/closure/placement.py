"""The hand's placement in the closure model: each turn closes onto the pose the device was put back in.

A turn by hand ends rotated by a small rho_j from where it began, so its calibrated closure is r_j = rho_j + noise,
not 0. rho_j has a tilt part (perpendicular to gravity u_j) and a heading part (about u_j):

- the tilt is measured by the accelerometer at the rests on either side (``calib.stages.placement``):
  rho_hat_j = (I - u u^T) rho_j + e_j, e_j ~ N(0, sd_j^2 (I - u u^T));
- the heading is not measured by anything but the closure itself; its prior is N(0, tau_h^2) (``heading_prior_deg``,
  the repeatability of putting the device back against the block: ``HEADING_PRIOR_DEG`` unless stated);
- the tilt's own prior N(0, tau_t^2 (I - u u^T)) has tau_t from the measured tilts themselves:
  E|rho_hat_j|^2 = 2 (tau_t^2 + sd_j^2), and 0 when the tilts are no larger than the accelerometer's noise makes them.

Marginalising rho_j out (everything is Gaussian and linear) leaves the closure residual r_j - s_j rho_hat_j, with
s_j = tau_t^2 / (tau_t^2 + sd_j^2), and the extra covariance s_j sd_j^2 (I - u u^T) + tau_h^2 u u^T added to the
noise's. A device put back exactly (tau_t = 0) leaves the model as it was; a turn whose tilt is not measured (no
accelerometer, no rest beside it) carries both parts as an isotropic prior of the larger of tau_t and tau_h.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calib.distributions import chi2_isf
from calib.errors import GyrocalError
from calib.stages.placement import TurnTilts
from calib.units import DEG

# The repeatability of the heading a device is put back with against the block, deg per turn (1 sigma). Measured:
# imucal's session against fixed stops closes its x and y turns about the vertical to 0.01-0.03 deg; an optical
# motion-capture recording of a hand-turned IMU came back 0.45 deg off; by eye without a block, 0.3-2 deg
# (docs/method.md, "The hand's placement").
HEADING_PRIOR_DEG = 0.1
TILT_TEST_ALPHA = 0.001  # tilts beyond the accelerometer's noise at this level are the hand's, and are modelled
MAX_HEADING_PRIOR_DEG = 10.0  # beyond this a turn's closure says nothing of its scale factor
MAX_DOF = 1e6  # degrees of freedom this many or more are reported as a normal interval's (inf)


@dataclass(frozen=True)
class HeadingSpread:
    """The heading spread a fit carried: ``spread_deg`` (1 sigma per turn), ``source`` ("estimated", "stated" or
    "default"), ``turns`` (those whose closure showed it), ``vertical`` (of those, the turns about the vertical),
    ``spread_sd_deg`` (its standard error, estimated only),
    ``dof`` (P,): each parameter's degrees of freedom for a Student-t interval (inf: normal), and
    ``sd_ratio`` (P,): its standard error over all the spreads the turns allow, over that at the one estimated, and
    ``interval_scale`` (P,): the scale of its Student-t interval, from the spreads the turns allow, at the weights'
    (NaN: its standard error)."""

    spread_deg: float
    source: str
    turns: int = 0
    spread_sd_deg: float | None = None
    dof: np.ndarray | None = None
    sd_ratio: np.ndarray | None = None  # (P,) each parameter's sd over the spreads allowed, over that at the spread
    vertical: int = 0
    interval_scale: np.ndarray | None = None

    def padded(self, P: int) -> HeadingSpread:
        """The same spread for a fit of P parameters: those beyond this one's normal and unwidened."""
        def pad(a: np.ndarray | None, fill: float) -> np.ndarray | None:
            return None if a is None else np.concatenate((a, np.full(P - a.size, fill)))

        return replace(self, dof=pad(self.dof, np.inf), sd_ratio=pad(self.sd_ratio, 1.0),
                       interval_scale=pad(self.interval_scale, np.nan))


@dataclass(frozen=True)
class PlacementModel:
    """What each turn's closure is expected to be, and the covariance the placement adds to it."""

    target: np.ndarray  # (J, 3) rad: the expected closure (the measured tilt, shrunk by its prior)
    cov: np.ndarray  # (J, 3, 3) rad^2
    tilt_prior_deg: float  # tau_t, from the measured tilts (the heading prior where none was measured)
    heading_prior_deg: float  # tau_h, as stated


def check_heading_prior(value: float | None) -> float:
    """The heading prior in deg: ``HEADING_PRIOR_DEG`` for None; GyrocalError for a value that is not one."""
    if value is None:
        return HEADING_PRIOR_DEG
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if not np.isfinite(v) or v < 0 or v > MAX_HEADING_PRIOR_DEG:
        raise GyrocalError(f"the heading prior is the standard deviation of the heading a device is put back with, in deg "
                           f"from 0 to {MAX_HEADING_PRIOR_DEG:g}; got {value!r}")
    return v


def tilt_prior_deg(tilts: TurnTilts) -> float:
    """tau_t: the spread of the hand's tilts beyond the accelerometer's noise, deg; 0 when the tilts are what the
    accelerometer's noise alone gives (their chi-square below its ``TILT_TEST_ALPHA`` quantile), so that a device put
    back exactly is calibrated as if the tilts had not been measured; NaN when none was measured."""
    m = tilts.measured
    if not m.any():
        return float("nan")
    square = np.sum(tilts.rotation_deg[m] ** 2, axis=1)
    sd2 = tilts.sd_deg[m] ** 2
    if float(np.sum(square / sd2)) < float(chi2_isf(TILT_TEST_ALPHA, 2 * int(m.sum()))):
        return 0.0
    return float(np.sqrt(max(0.0, float(np.mean(square / 2.0 - sd2)))))


def placement_model(tilts: TurnTilts, heading_prior_deg: float) -> PlacementModel:
    """The placement model of J turns from their measured tilts and the stated heading prior (deg)."""
    J = tilts.sd_deg.shape[0]
    tau_h = float(heading_prior_deg)
    tau_t = tilt_prior_deg(tilts)
    if not np.isfinite(tau_t):
        tau_t = tau_h
    target = np.zeros((J, 3))
    cov = np.zeros((J, 3, 3))
    eye = np.eye(3)
    for j in range(J):
        if not tilts.measured[j]:
            cov[j] = max(tau_t, tau_h) ** 2 * eye
            continue
        sd, u = tilts.sd_deg[j], tilts.up[j]
        shrink = tau_t**2 / (tau_t**2 + sd**2) if tau_t > 0 else 0.0
        flat = eye - np.outer(u, u)
        target[j] = shrink * flat @ tilts.rotation_deg[j]
        cov[j] = shrink * sd**2 * flat + tau_h**2 * np.outer(u, u)
    return PlacementModel(target * DEG, cov * DEG**2, tau_t, tau_h)
