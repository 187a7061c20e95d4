"""A verification turn: found between two rests, measured raw and calibrated; the true calibration gives 360 degrees
within the stated uncertainty, a scale factor 1 % off does not; no turn is said plainly."""

from __future__ import annotations

import numpy as np
import pytest

from calib.apply.correction import Correction
from calib.estimators.closure.estimator import calibrate_closure
from calib.judge.verification import FULL_TURN_DEG, NoVerificationTurn, find_turn, verify_turn
from calib.recording import Recording
from calib.simulator import simulate


@pytest.fixture(scope="module")
def recorded() -> tuple[Recording, object]:
    return simulate(5, noise=0.03)


def test_the_estimated_calibration_measures_a_full_turn_as_360_degrees(recorded) -> None:
    rec, truth = recorded
    result = calibrate_closure(rec)
    v = verify_turn(rec, Correction.from_result(result), result.to_json()["uncertainty"])
    assert v.confirmed and v.dominant_axis == "x" and 0 < v.uncertainty_deg < 0.1
    assert abs(v.calibrated_deg - FULL_TURN_DEG) < 3 * v.uncertainty_deg + 0.05
    # the raw reading of the turn is off by the x scale factor and bias: m = (g - b) / k, so raw = (360 - b_x T) / k_x
    assert v.raw_deg == pytest.approx((FULL_TURN_DEG - truth.b[0] * (v.end_s - v.start_s)) / truth.k[0], rel=3e-3)
    assert v.to_json()["error_deg"] == pytest.approx(v.calibrated_deg - 360.0)


def test_a_scale_factor_one_percent_off_is_not_confirmed(recorded) -> None:
    rec, truth = recorded
    off = Correction(K=np.diag(truth.k * np.array([1.01, 1.0, 1.0])), b=np.asarray(truth.b))
    v = verify_turn(rec, off, {"k": [1e-4] * 3, "b": [1e-3] * 3})
    assert not v.confirmed and 3.0 < v.error_deg < 4.5  # about 1 % of the turn


def test_a_recording_without_a_full_turn_between_rests_is_refused(recorded) -> None:
    rec, truth = recorded
    still = rec.slice(0, 250)  # the first rest only
    assert find_turn(still) is None
    with pytest.raises(NoVerificationTurn, match="turn it once all the way round"):
        verify_turn(still, Correction(K=np.diag(truth.k), b=np.asarray(truth.b)))
