"""The files the robotics tools load, read back by readers written from each tool's documented format: Kalibr's
imu.yaml (its wiki, "IMU Noise Model") and OpenVINS's kalibr_imu_chain.yaml (docs/propagation-analytical.dox and its
loader, ov_msckf/src/core/VioManagerOptions.h)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from robotics_readers import openvins_correct, read_kalibr_imu, read_openvins

from calib.apply.correction import Correction
from calib.errors import GyrocalError
from calib.exports.kalibr import kalibr_imu_yaml
from calib.exports.openvins import openvins_imu_chain, ql
from calib.noise.analysis import noise
from calib.simulator.rest_noise import RestNoise, simulate_rest

G0 = 9.80665
RAD = math.pi / 180


def test_kalibrs_imu_yaml_holds_the_rests_noise_in_si_units() -> None:
    gyro, accel = RestNoise(density=0.01, random_walk=3e-4), RestNoise(density=1e-4, random_walk=3e-6)
    report = noise(simulate_rest(11, 3600.0, 100.0, gyro, accel))
    d = read_kalibr_imu(kalibr_imu_yaml(report, "/wearable/imu"))
    assert d["rostopic"] == "/wearable/imu" and d["update_rate"] == 100
    # the largest axis's: within a few per cent of the truth for the densities, within a factor for the walks
    assert d["gyroscope_noise_density"] == pytest.approx(0.01 * RAD, rel=0.03)
    assert d["accelerometer_noise_density"] == pytest.approx(1e-4 * G0, rel=0.03)
    assert d["gyroscope_random_walk"] == pytest.approx(3e-4 * RAD, rel=0.6)
    assert d["accelerometer_random_walk"] == pytest.approx(3e-6 * G0, rel=0.6)


def test_kalibrs_file_needs_the_accelerometer() -> None:
    report = noise(simulate_rest(1, 600.0, 100.0, RestNoise(density=0.01)))
    with pytest.raises(GyrocalError, match="needs the accelerometer's noise too"):
        kalibr_imu_yaml(report)


def test_openvins_corrects_readings_as_gyrocal_does() -> None:
    rng = np.random.default_rng(4)
    K = np.eye(3) + 0.02 * rng.standard_normal((3, 3))  # scale and misalignment, not triangular
    s, t = 1 + 0.01 * rng.standard_normal(3), np.array([[1, -0.004, 0.003], [0, 1, -0.002], [0, 0, 1.0]])
    corr = Correction(K=K, b=np.array([0.3, -0.2, 0.1]), G=0.05 * rng.standard_normal((3, 3)), A=t @ np.diag(s),
                      o=np.array([0.01, -0.02, 0.015]))
    ov = read_openvins(openvins_imu_chain(corr, topic="/imu0", rate_hz=100.0))
    m = 50 * rng.standard_normal((200, 3))
    r = rng.standard_normal((200, 3))
    g_true, a_true = corr.apply(m, r)
    w, a = openvins_correct(ov, m * RAD, r * G0)
    np.testing.assert_allclose(a / G0, a_true, atol=1e-9)
    np.testing.assert_allclose(w / RAD, g_true, atol=1e-7)


def test_the_ql_factors_are_a_rotation_and_a_lower_triangle() -> None:
    M = np.array([[1.01, 0.02, -0.01], [0.015, 0.99, 0.03], [-0.02, 0.01, 1.02]])
    Q, L = ql(M)
    np.testing.assert_allclose(Q @ L, M, atol=1e-12)
    np.testing.assert_allclose(Q @ Q.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(Q) == pytest.approx(1.0) and np.allclose(np.triu(L, 1), 0) and np.all(np.diag(L) > 0)
    with pytest.raises(GyrocalError, match="left-handed"):
        ql(np.diag([1.0, 1.0, -1.0]))


def test_without_the_accelerometers_calibration_openvins_gets_its_default_and_is_told() -> None:
    corr = Correction(K=np.diag([1.01, 0.99, 1.02]), b=np.array([0.1, 0.0, -0.1]))
    text = openvins_imu_chain(corr)
    assert "the accelerometer was not calibrated" in text
    ov = read_openvins(text)
    np.testing.assert_allclose(ov["Da"], np.eye(3))
    np.testing.assert_allclose(ov["b_a"], 0.0)
    w, _ = openvins_correct(ov, np.radians([[10.0, 20.0, 30.0]]), np.array([[0.0, 0.0, G0]]))
    np.testing.assert_allclose(np.degrees(w), corr.apply(np.array([[10.0, 20.0, 30.0]]))[0], atol=1e-9)


def test_openvins_file_carries_the_rests_noise_when_given() -> None:
    report = noise(simulate_rest(2, 900.0, 100.0, RestNoise(density=0.01), RestNoise(density=1e-4)))
    corr = Correction(K=np.eye(3), b=np.zeros(3), A=np.eye(3), o=np.zeros(3))
    imu = yaml.safe_load(openvins_imu_chain(corr, report).split("\n", 1)[1])["imu0"]
    assert imu["gyroscope_noise_density"] == pytest.approx(0.01 * RAD, rel=0.03)
    assert imu["update_rate"] == 100 and imu["time_offset"] == 0.0 and np.shape(imu["T_i_b"]) == (4, 4)
