"""What a result's checks tell an operator: how much of each allowance is used, which pass close to their limit,
and how well a full turn measures before and after the calibration."""

from __future__ import annotations

import numpy as np
import pytest

from calib.judge.acceptance import NEAR_LIMIT_USED, Tolerances, evaluate, turn_accuracy
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
    assert acc is not None
    # a full turn reads 360/k raw: the worst axis is the one whose k is furthest from 1
    expected = max(abs(360.0 / k - 360.0) for k in truth.k)
    assert acc["before_deg"] == pytest.approx(expected, abs=3.0)
    assert acc["after_deg"] < 0.1


def test_turn_accuracy_is_none_without_the_closure_turn_rows() -> None:
    assert turn_accuracy(_result([1, 1, 1], [0, 0, 0])) is None
