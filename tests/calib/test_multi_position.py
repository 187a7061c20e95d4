"""Gyroscope calibration from re-orientations between rests (calib.multi_position): simulation and imu_tk's session."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calib.accel import AccelCalibration, AccelCalibrationError
from calib.api import calibrate_protocol
from calib.errors import CalibrationError, ProtocolError
from calib.multi_position import calibrate_multi_position
from calib.simulator import simulate
from calib.simulator.lab_scripts import multi_position_script


def test_recovers_k_and_b_from_re_orientations_with_honest_uncertainty():
    z, err = [], []
    for seed in range(24):
        rng = np.random.default_rng(500 + seed)
        rec, truth = simulate(seed, noise=0.05, fs=100.0, script=multi_position_script(rng), accel_noise_g=0.005)
        res = calibrate_multi_position(rec)
        e = np.concatenate([res.k - truth.k, res.b - truth.b])
        err.append(e)
        z.append(e / np.concatenate([res.k_std, res.b_std]))
        assert res.quality["constraints"] == {"rests": 37, "gravity_motions": 36, "full_turns": 0}
        assert res.K is not None and np.abs(res.K - np.diag(np.diag(res.K))).max() < 0.005  # the simulated axes are aligned
    err_a, z_a = np.abs(np.array(err)), np.array(z)
    assert np.all(err_a[:, :3] < 1e-3), "scale factors to 0.1 %"
    assert np.all(err_a[:, 3:] < 0.02), "biases to 0.02 deg/s"
    assert np.all(np.abs(z_a) < 5.0)
    sd = z_a.std(axis=0)
    assert np.all((sd > 0.6) & (sd < 1.6)), sd  # 24 runs: the sd of a unit normal's sample sd is about 0.15


def test_turns_about_the_vertical_only_cannot_calibrate_and_say_why():
    rng = np.random.default_rng(3)
    rec, _ = simulate(3, noise=0.05, fs=100.0, script=multi_position_script(rng, n=8, first_rest_s=10.0, vertical_only=True))
    with pytest.raises(AccelCalibrationError, match="orientations are too alike"):
        calibrate_multi_position(rec)  # every rest flat: the accelerometer cannot be calibrated either
    nominal = AccelCalibration(scale=np.ones(3), offset=np.zeros(3), misalignment=np.zeros(3))
    with pytest.raises(CalibrationError, match="tilted"):
        calibrate_multi_position(rec, accel=nominal)


def test_needs_the_accelerometer_and_enough_motions():
    rng = np.random.default_rng(4)
    rec, _ = simulate(4, noise=0.05, fs=100.0, script=multi_position_script(rng, n=3, first_rest_s=10.0))
    with pytest.raises(ProtocolError, match="at least 6"):
        calibrate_multi_position(rec)
    from dataclasses import replace

    with pytest.raises(ProtocolError, match="needs the accelerometer"):
        calibrate_multi_position(replace(rec, accel=None))


def test_auto_keeps_the_paper_protocol_for_paper_recordings_and_falls_back_for_re_orientations():
    rec, _ = simulate(1, noise=0.05)
    assert calibrate_protocol(rec)[1] == "paper"
    rng = np.random.default_rng(5)
    rec, truth = simulate(5, noise=0.05, fs=100.0, script=multi_position_script(rng, n=12, first_rest_s=20.0))
    result, protocol = calibrate_protocol(rec)
    assert protocol == "multi-position" and np.all(np.abs(result.k - truth.k) < 2e-3)
    with pytest.raises(ProtocolError):
        calibrate_protocol(rec, "paper")


def test_imu_tk_xsens_session_is_calibrated_from_its_37_re_orientations(real_data: Path):
    from calib.imu_tk_io import read_imu_tk

    rec = read_imu_tk(real_data / "imu_tk" / "xsens_gyro.mat", real_data / "imu_tk" / "xsens_acc.mat")
    res, protocol = calibrate_protocol(rec)
    assert protocol == "multi-position"
    q = res.quality
    assert q["constraints"] == {"rests": 38, "gravity_motions": 37, "full_turns": 0}
    assert len(q["gravity_residual_deg"]) == 37
    assert q["gravity_residual_rms_deg"] < 1.0  # each motion's end gravity carried back to its start, after calibration
    assert np.all(res.k_std < 0.005) and np.all(res.b_std < 0.05)
