"""What a result's checks tell an operator: how much of each allowance is used, which pass close to their limit,
and how well a full turn measures before and after the calibration."""

from __future__ import annotations

import numpy as np
import pytest

from calib.judge.acceptance import NEAR_LIMIT_USED, Tolerances, evaluate, turn_accuracy
from calib.judge.judgement import judge
from calib.pipeline import calibrate
from calib.result import CalibrationResult
from calib.simulator import simulate


def _result(k: list[float], b: list[float]) -> CalibrationResult:
    return CalibrationResult(k=np.array(k), b=np.array(b), method="closure", stages=[])


@pytest.mark.parametrize(
    ("k", "used"),
    [(1.0, 0.0), (1.19, 0.95), (1.02, 0.1), (0.81, 0.95), (0.9, 0.5)],
)
def test_a_scale_factor_uses_its_allowance_from_one_towards_either_limit(k: float, used: float) -> None:
    check = next(c for c in evaluate(_result([k, 1.0, 1.0], [0.0, 0.0, 0.0]), Tolerances()) if c.name == "k")
    assert check.ok
    assert check.used == pytest.approx(used)
    assert check.near_limit is (used >= NEAR_LIMIT_USED)


def test_a_bias_near_its_limit_is_marked_and_one_beyond_is_not_near_but_failed() -> None:
    checks = {c.axis: c for c in evaluate(_result([1, 1, 1], [9.1, -2.0, 10.5]), Tolerances()) if c.name == "b"}
    assert checks["x"].ok and checks["x"].near_limit
    assert checks["y"].ok and not checks["y"].near_limit
    assert not checks["z"].ok and not checks["z"].near_limit


def test_a_value_that_is_not_finite_uses_no_allowance_and_fails() -> None:
    check = next(c for c in evaluate(_result([float("nan"), 1, 1], [0, 0, 0]), Tolerances()) if c.name == "k")
    assert check.ok is False and check.near_limit is False and check.used is None


def test_turn_accuracy_reads_the_raw_full_turn_before_and_the_closure_after() -> None:
    rec, truth = simulate(3, noise=0.03)
    acc = turn_accuracy(calibrate(rec))
    assert acc is not None and acc["before_with"] == "raw"
    # a full turn reads 360/k raw: the worst axis is the one whose k is furthest from 1
    expected = max(abs(360.0 / k - 360.0) for k in truth.k)
    assert acc["before_deg"] == pytest.approx(expected, abs=0.05)
    assert acc["after_deg"] < 0.1


def test_turn_accuracy_compares_with_the_calibration_in_force_when_the_device_has_one() -> None:
    """"Before" is what the device used until now: through the calibration in force a full turn reads k_old/k_new of
    360° (about 360° when the sensor has not changed), and the judgement takes the newest stored calibration."""
    rec, truth = simulate(3, noise=0.03)
    res = calibrate(rec)
    b = [float(v) for v in truth.b]
    same = {"id": 7, "k": [float(v) for v in truth.k], "K": None, "b": b}
    acc = turn_accuracy(res, same)
    assert acc is not None and acc["before_with"] == "calibration" and acc["before_calibration_id"] == 7
    assert acc["before_deg"] < 0.05  # the sensor is the one that calibration was made on
    shifted = {"id": 8, "k": [float(truth.k[0]) * 1.01, float(truth.k[1]), float(truth.k[2])], "b": b}
    assert turn_accuracy(res, shifted)["before_deg"] == pytest.approx(3.6, abs=0.5)  # a 1 % change of k_x: 3.6°
    assert judge(res, Tolerances(), [shifted, same]).accuracy["before_calibration_id"] == 8
    assert judge(res, Tolerances(), []).accuracy["before_with"] == "raw"


def test_turn_accuracy_is_none_without_the_closure_turn_rows() -> None:
    assert turn_accuracy(_result([1, 1, 1], [0, 0, 0])) is None
