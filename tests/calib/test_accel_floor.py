"""The accelerometer's noise floor (``calib.noise.accel_floor``): found where rest means scatter beyond white noise,
not where they do not, and counted in imu_tk's rests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import calib.estimators.multi_position.estimator as mp
from calib.estimators.multi_position.estimator import calibrate_multi_position
from calib.noise.accel_floor import FLOOR_ALPHA, NO_FLOOR, accel_floor

FS = 100.0
SPANS = [(0, 5000)] + [(5000 + 1000 * i, 5000 + 1000 * i + 700) for i in range(30)]  # a 50 s rest, then 7 s rests


def _readings(rng: np.random.Generator, white_g: float, floor_g: np.ndarray) -> np.ndarray:
    """White noise plus an offset drawn afresh every 7 s (700 samples): rest means over 7 s scatter by ``floor_g``."""
    n = 5000 + 1000 * 30
    steps = np.repeat(rng.standard_normal((n // 700 + 1, 3)) * floor_g, 700, axis=0)[:n]
    return white_g * rng.standard_normal((n, 3)) + steps


def test_white_noise_shows_a_floor_only_as_often_as_its_false_positive_rate():
    rng = np.random.default_rng(3)
    found = sum(int(np.count_nonzero(accel_floor(_readings(rng, 1e-3, np.zeros(3)), SPANS, np.ones(3), FS).sd))
                for _ in range(300))
    assert found / 900 < 2.5 * FLOOR_ALPHA


def test_a_floor_is_measured_axis_by_axis_on_the_longest_rest():
    rng = np.random.default_rng(4)
    truth = np.array([0.0, 1e-4, 3e-4])  # g; the white part of a 7 s mean is 1e-3 / sqrt(700) = 3.8e-5 g
    found = np.array([accel_floor(_readings(rng, 1e-3, truth), SPANS, np.ones(3), FS).sd for _ in range(200)])
    median = np.median(found, axis=0)
    assert median[0] == 0.0
    assert median[1:] == pytest.approx(truth[1:], rel=0.3)
    floor = accel_floor(_readings(rng, 1e-3, truth), SPANS, np.ones(3), FS)
    assert floor.rest == 0 and floor.tau_s == pytest.approx(7.0) and floor.measured


def test_no_rest_long_enough_leaves_it_unmeasured():
    rng = np.random.default_rng(5)
    floor = accel_floor(_readings(rng, 1e-3, np.full(3, 3e-4)), SPANS[1:], np.ones(3), FS)
    assert floor is NO_FLOOR and not floor.measured and floor.to_dict()["per_axis_mg"] == [0.0, 0.0, 0.0]


def test_imu_tk_accelerometer_floor_makes_its_magnitudes_agree(real_data: Path, monkeypatch: pytest.MonkeyPatch):
    """Xsens' accelerometer levels off at ~0.06-0.08 mg on y and z over 8 s (the Allan deviation of its 52 s rest):
    counted, |a| = 1 g is within a few times its noise instead of 11 times, and the gyro's uncertainties are no
    longer inflated by the accelerometer's misfit."""
    from calib.io.imu_tk import read_imu_tk

    rec = read_imu_tk(real_data / "imu_tk" / "xsens_gyro.mat", real_data / "imu_tk" / "xsens_acc.mat")
    res = calibrate_multi_position(rec)
    floor = res.quality["accelerometer_floor"]
    assert floor["measured"] and floor["rest"] == 0 and floor["per_axis_mg"][0] == 0.0
    assert 0.03 < floor["per_axis_mg"][1] < 0.12 and 0.04 < floor["per_axis_mg"][2] < 0.15
    ratio = res.quality["constraint_fit"]["accelerometer_magnitude"]["ratio"]

    monkeypatch.setattr(mp, "accel_floor", lambda *a: NO_FLOOR)
    white = calibrate_multi_position(rec)
    assert white.quality["accelerometer_floor"]["measured"] is False
    white_ratio = white.quality["constraint_fit"]["accelerometer_magnitude"]["ratio"]
    assert white_ratio > 8.0 and ratio < 4.0
    assert res.quality["birge_ratio"] < 0.8 * white.quality["birge_ratio"]
    assert np.all(res.k_std < 0.85 * white.k_std)
    assert np.max(np.abs(res.k - white.k)) < 1e-4  # the estimate barely moves; its uncertainty does
