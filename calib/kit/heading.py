"""The tray's heading spread: one tray, one hand, so every wearable in it carries the same one.

It is learned from the kit's mean recording in the fit the wearables' axes rest on (``calib.kit.axes``' refit, with
the prior on the reference's tilt), unless stated. The mean's first fit, its K diagonal where its own turns did not
identify the tilt, reads the cross-axis part of the closures as heading: on a tray put back exactly it learned up to
0.4 deg, and carried into the fit with the tilt, k_z took the turn about the vertical's closure (docs/method.md,
"Non-orthogonal axes").
"""

from __future__ import annotations

from calib.estimators.closure.estimator import calibrate_closure
from calib.estimators.closure.fit import KPrior
from calib.recording import Recording
from calib.result import CalibrationResult

# the spread every wearable's fit carries (deg per turn; None: each fit's default) and where it came from: "stated",
# "kit" (learned from the kit's mean recording) or "default"
Tray = tuple[float | None, str]


def tray_heading(mean: CalibrationResult, heading_prior_deg: float | None) -> Tray:
    """The tray's heading spread as ``mean`` (a calibration of the kit's mean recording) learned it: as stated, else
    what it showed, else (no turn showed it) each fit's default."""
    if heading_prior_deg is not None:
        return heading_prior_deg, "stated"
    placement = mean.quality.get("placement")
    heading = placement.get("heading") if placement else None
    if heading is not None and heading["source"] == "estimated" and heading["spread_deg"] is not None:
        return float(heading["spread_deg"]), "kit"
    return None, "default"


class MeanRefit:
    """The kit's mean recording ``rec`` calibrated again on ``mean``'s stages with a prior on K's off-diagonal terms
    (a ``calib.kit.axes.Refit``, for a mean the closure estimator calibrated). The tray's spread is learned in it
    (unless stated), with the tilt, then carried as the tray's, as every wearable carries it. ``tray``: the spread the
    last refit carried, None until asked."""

    def __init__(self, rec: Recording, mean: CalibrationResult, heading_prior_deg: float | None) -> None:
        self.rec, self.mean, self.heading_prior_deg = rec, mean, heading_prior_deg
        self.tray: Tray | None = None

    def __call__(self, prior: KPrior) -> CalibrationResult:
        if self.heading_prior_deg is not None:
            self.tray = tray_heading(self.mean, self.heading_prior_deg)
        else:
            learned = calibrate_closure(self.rec, stages=self.mean.stages, k_prior=prior)
            self.tray = tray_heading(learned, None)
            if self.tray[0] is None:  # no turn showed it: the default, as that fit carried
                return learned
        return calibrate_closure(self.rec, stages=self.mean.stages, heading_prior_deg=self.tray[0], k_prior=prior,
                                 heading_source=self.tray[1])
