"""The rate-table method: a turntable (or servomotor) turns the device at known constant rates.

For each axis, the mean reading over each run (from rest to rest, so the table's start and stop are inside)
is regressed on the run's mean rate (its commanded angle over its duration; a table's position is exact):
g = k m + b along that axis, by least squares over the runs (both directions, each rate), with the
regression's standard errors. The conventional laboratory calibration ("six angular rate method": three
rates each way), the paper's gold standard; a servomotor turns at one rate each way, less exactly.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from calib.errors import CalibrationError
from calib.recording import Recording
from calib.result import CalibrationResult
from calib.stages.stage import AXES, Stage

METHOD = "rate-table"


@dataclass(frozen=True)
class RateRun:
    """One run: samples [start, end) about ``axis`` at a mean rate ``rate_dps`` (its angle over its duration)."""

    start: int
    end: int
    axis: str
    rate_dps: float


def calibrate_rate_table(rec: Recording, runs: Sequence[RateRun], stages: list[Stage] | None = None) -> CalibrationResult:
    """k and b of each axis from constant-rate runs; needs two different rates per axis."""
    k, b, k_std, b_std = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for i, axis in enumerate(AXES):
        mine = [r for r in runs if r.axis == axis]
        rates = np.array([r.rate_dps for r in mine])
        if np.unique(rates).size < 2:
            raise CalibrationError(f"the rate-table method needs at least two different rates about {axis}")
        means = [rec.gyro[r.start:r.end, i].mean() for r in mine]
        A = np.column_stack([means, np.ones(len(means))])
        coef, *_ = np.linalg.lstsq(A, rates, rcond=None)
        resid = rates - A @ coef
        dof = max(len(rates) - 2, 1)
        cov = np.linalg.inv(A.T @ A) * float(resid @ resid) / dof if len(rates) > 2 else np.full((2, 2), np.nan)
        k[i], b[i] = coef
        k_std[i], b_std[i] = np.sqrt(np.diag(cov))
    return CalibrationResult(k=k, b=b, method=METHOD, stages=list(stages or []), k_std=k_std, b_std=b_std,
                             quality={"model": "diagonal", "runs": len(runs)}, sample_rate_hz=rec.fs, n_samples=len(rec))
