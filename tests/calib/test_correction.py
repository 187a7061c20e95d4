"""Applying a calibration: a result's correction recovers the true rates, gyrocal's calibration JSON round-trips,
the real imucal package loads the file gyrocal writes for it and corrects readings exactly as gyrocal does, and
gyrocal reads imucal's files back; bad files are refused with what is wrong."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from calib.apply.correction import Correction, CorrectionFileError, corrected
from calib.pipeline import calibrate
from calib.simulator import simulate
from calib.units import STANDARD_GRAVITY as G0


@pytest.fixture(scope="module")
def calibrated() -> tuple[object, object, Correction]:
    rec, truth = simulate(11, noise=0.03)
    return rec, truth, Correction.from_result(calibrate(rec))


def test_a_results_correction_recovers_the_true_rates(calibrated: tuple[object, object, Correction]) -> None:
    rec, truth, corr = calibrated
    out = corrected(rec, corr)  # type: ignore[arg-type]
    err = out.gyro - truth.rate  # type: ignore[attr-defined]
    raw_err = rec.gyro - truth.rate  # type: ignore[attr-defined]
    # what is left is the sensor's white noise (0.03 deg/s); before, up to 20 % of 300 deg/s and a few deg/s of bias
    assert np.sqrt(np.mean(err**2)) < 0.05 and np.sqrt(np.mean(raw_err**2)) > 3.0
    assert np.array_equal(out.t, rec.t) and out.accel is rec.accel  # the accelerometer is not calibrated here


def _full() -> Correction:
    rng = np.random.default_rng(3)
    K = np.diag([1.12, 0.91, 1.04]) + np.triu(rng.normal(0, 0.01, (3, 3)), 1)
    A = np.array([[0.98, -0.004, 0.002], [0.0, 1.01, 0.003], [0.0, 0.0, 0.995]])
    return Correction(K=K, b=np.array([0.5, -1.2, 2.0]), G=rng.normal(0, 0.05, (3, 3)), A=A, o=np.array([0.01, -0.02, 0.03]))


def test_gyrocals_calibration_json_round_trips() -> None:
    corr = _full()
    back = Correction.from_json(json.loads(json.dumps(corr.to_json())))
    gyro, accel = np.random.default_rng(1).normal(0, 50, (100, 3)), np.random.default_rng(2).normal(0, 1, (100, 3))
    g1, a1 = corr.apply(gyro, accel)
    g2, a2 = back.apply(gyro, accel)
    assert np.allclose(g1, g2, atol=1e-12) and a1 is not None and a2 is not None and np.allclose(a1, a2, atol=1e-12)
    # the least a file needs: k and b
    small = Correction.from_json({"k": [1.1, 0.9, 1.0], "b": [1, 2, 3]})
    assert np.allclose(small.apply(np.ones((1, 3)))[0], [[2.1, 2.9, 4.0]])


def test_the_real_imucal_loads_the_file_gyrocal_writes_and_corrects_the_same(tmp_path: Path) -> None:
    from imucal.management import load_calibration_info

    corr = _full()
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps(corr.to_imucal("written by gyrocal")))
    info = load_calibration_info(path)
    assert type(info).__name__ == "FerrarisCalibrationInfo"
    gyro, accel = np.random.default_rng(4).normal(0, 80, (200, 3)), np.random.default_rng(5).normal(0, 1, (200, 3))
    acc_imucal, gyr_imucal = info.calibrate(accel, gyro, acc_unit="g", gyr_unit="deg/s")
    gyr_ours, acc_ours = corr.apply(gyro, accel)
    assert acc_ours is not None
    assert np.allclose(gyr_imucal, gyr_ours, atol=1e-9) and np.allclose(acc_imucal, acc_ours, atol=1e-12)
    # and back: gyrocal reads imucal's file to the same correction
    again = Correction.from_json(json.loads(info.to_json()))
    assert again.source == "imucal" and np.allclose(again.apply(gyro, accel)[0], gyr_ours, atol=1e-9)


def test_an_imucal_file_in_metres_per_second_squared_is_read_in_g() -> None:
    from imucal import FerrarisCalibrationInfo

    K_ga = np.full((3, 3), 0.001)  # (deg/s) per (m/s^2)
    A = np.array([[1.02, 0.01, 0.0], [0.0, 0.97, -0.02], [0.0, 0.0, 1.01]])
    info = FerrarisCalibrationInfo(acc_unit="m/s^2", gyr_unit="deg/s", from_acc_unit="m/s^2", from_gyr_unit="deg/s",
                                   K_a=np.linalg.inv(A), R_a=np.eye(3), b_a=np.array([0.1, -0.2, 0.05]),
                                   K_g=np.diag([1 / 1.1, 1 / 0.9, 1.0]), R_g=np.eye(3), K_ga=K_ga, b_g=np.array([0.1, -0.2, 0.3]))
    corr = Correction.from_json(json.loads(info.to_json()))
    gyro, accel_g = np.random.default_rng(6).normal(0, 60, (50, 3)), np.random.default_rng(7).normal(0, 1, (50, 3))
    acc_imucal, gyr_imucal = info.calibrate(accel_g * G0, gyro, acc_unit="m/s^2", gyr_unit="deg/s")
    gyr_ours, acc_ours = corr.apply(gyro, accel_g)
    assert corr.G is not None and np.allclose(corr.G, K_ga * G0)
    assert np.allclose(gyr_ours, gyr_imucal, atol=1e-9)
    assert acc_ours is not None and np.allclose(acc_ours * G0, acc_imucal, atol=1e-9)


def test_an_imucal_file_for_raw_counts_is_refused_with_why() -> None:
    doc = {"cal_type": "Ferraris", "from_acc_unit": "a.u.", "acc_unit": "m/s^2"}
    with pytest.raises(CorrectionFileError, match="input acceleration is in 'a.u.'"):
        Correction.from_json(doc)


@pytest.mark.parametrize(("doc", "words"), [
    ({"k": [1, 1], "b": [0, 0, 0]}, "three finite numbers"),
    ({"b": [0, 0, 0]}, "needs \"k\" and \"b\""),
    ({"k": [1, 0, 1], "b": [0, 0, 0]}, "singular"),
    ({"cal_type": "Turntable"}, "Ferraris"),
    ({"cal_type": "Ferraris", "acc_unit": "g", "gyr_unit": "deg/s"}, "has no"),
    ([1, 2, 3], "JSON object"),
])
def test_a_file_that_is_no_calibration_is_refused_with_what_is_wrong(doc: object, words: str) -> None:
    with pytest.raises(CorrectionFileError, match=words):
        Correction.from_json(doc)
