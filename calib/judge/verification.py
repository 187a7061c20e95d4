"""Verifying a calibration in the field: one more full turn, about any axis, against the same block (docs/lifecycle.md,
"Verified in the field").

The turn is found by stage detection: a rest, one motion, a rest. Its angle is swept about the turn's own axis
(the direction of the rates integrated over it), from the raw readings m and from the calibrated rates g = K m + b.
A full turn against the block is 360 degrees; the calibrated angle's uncertainty comes from the calibration's (its
k and b along that axis) and from the sensor's noise over the turn, and the calibration is confirmed when the
calibrated angle is within three of those uncertainties and the block's placement allowance of 360.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, computed_field

from calib.apply.correction import Correction
from calib.errors import GyrocalError
from calib.recording import Recording, sample_intervals
from calib.stages.detector import detect_stages
from calib.stages.stage import Stage
from calib.units import FULL_TURN_DEG

PLACEMENT_DEG = 0.5  # how closely a hand puts the device back against the block
MIN_REST_S = 0.8  # the rests before and after the turn
MIN_TURN_DEG = 270.0  # a motion smaller than this is not the verification turn


class NoVerificationTurn(GyrocalError):
    """The recording holds no rest, full turn, rest; the message says what was found instead."""


class TurnVerification(BaseModel):
    """One verification turn: its axis and times, its angle raw and calibrated (deg), and the calibrated angle's
    standard uncertainty; the result a verification session holds."""

    model_config = ConfigDict(frozen=True)
    axis: list[float] = Field(description="unit vector of the turn's axis, sensor frame")
    dominant_axis: str
    start_s: float
    end_s: float
    raw_deg: float
    calibrated_deg: float
    uncertainty_deg: float

    @computed_field  # type: ignore[prop-decorator]
    @property
    def error_deg(self) -> float:
        """The calibrated angle minus 360°."""
        return self.calibrated_deg - FULL_TURN_DEG

    @computed_field  # type: ignore[prop-decorator]
    @property
    def confirmed(self) -> bool:
        """Within 3 standard uncertainties plus the placement allowance."""
        return abs(self.error_deg) <= 3.0 * self.uncertainty_deg + PLACEMENT_DEG

    @computed_field  # type: ignore[prop-decorator]
    @property
    def placement_allowance_deg(self) -> float:
        """How closely a hand puts the device back against the block."""
        return PLACEMENT_DEG

    def to_json(self) -> dict[str, Any]:
        """JSON-ready form, with its error, verdict and allowance."""
        return self.model_dump(mode="json")


def find_turn(rec: Recording) -> tuple[Stage, Stage, Stage] | None:
    """The first rest, motion, rest of the recording whose motion sweeps at least MIN_TURN_DEG (None: none yet)."""
    stages = detect_stages(rec)
    for before, turn, after in zip(stages, stages[1:], stages[2:], strict=False):
        if (before.kind == "still" and after.kind == "still" and turn.kind != "still"
                and before.duration_s >= MIN_REST_S and after.duration_s >= MIN_REST_S):
            swept = np.abs(rec.gyro[turn.start:turn.end] * sample_intervals(rec.t[turn.start:turn.end])[:, None]).sum(axis=0)
            if swept.max() >= MIN_TURN_DEG:
                return before, turn, after
    return None


def _swept(rates: np.ndarray, dt: np.ndarray) -> tuple[np.ndarray, float]:
    total = (rates * dt[:, None]).sum(axis=0)
    axis = total / np.linalg.norm(total)
    return axis, float((rates @ axis * dt).sum())


def verify_turn(rec: Recording, correction: Correction, uncertainty: dict[str, Any] | None = None) -> TurnVerification:
    """The verification turn of ``rec`` measured raw and with ``correction``; ``uncertainty`` the calibration's
    ``{"k": [3 std], "b": [3 std]}`` (None: the calibration's own uncertainty is left out). Raises
    NoVerificationTurn when the recording holds no rest, full turn, rest."""
    found = find_turn(rec)
    if found is None:
        raise NoVerificationTurn("no full turn between two rests was found: hold the device still against the block, turn it "
                                 "once all the way round about any axis, back against the block, and hold it still again")
    before, turn, _ = found
    span = slice(turn.start, turn.end)
    dt = rec.intervals_s[span]
    calibrated, _ = correction.apply(rec.gyro[span], None if rec.accel is None else rec.accel[span])
    axis, cal_deg = _swept(calibrated, dt)
    raw_axis, raw_deg = _swept(rec.gyro[span], dt)
    sign = np.sign(cal_deg) or 1.0
    duration = float(dt.sum())
    noise = float(np.std(rec.gyro[before.start:before.end] @ raw_axis)) if before.n > 2 else 0.0
    var = noise**2 * float((dt**2).sum())
    if uncertainty:
        sk = np.asarray(uncertainty.get("k") or np.zeros(3), float)
        sb = np.asarray(uncertainty.get("b") or np.zeros(3), float)
        var += float((axis**2) @ sk**2) * FULL_TURN_DEG**2 + float((axis**2) @ sb**2) * duration**2
    return TurnVerification(
        axis=[float(v) for v in axis * sign], dominant_axis="xyz"[int(np.argmax(np.abs(axis)))],
        start_s=float(turn.start_s), end_s=float(turn.end_s), raw_deg=abs(raw_deg), calibrated_deg=abs(cal_deg),
        uncertainty_deg=float(np.sqrt(var)),
    )
