"""Gyroscope calibration from re-orientations between rests (calib.estimators.multi_position.estimator): simulation and imu_tk's session."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calib.apply.correction import Correction
from calib.effects.axes import GSensitivity
from calib.errors import CalibrationError, ProtocolError
from calib.estimators.accel import AccelCalibration, AccelCalibrationError
from calib.estimators.multi_position.estimator import calibrate_multi_position
from calib.pipeline import calibrate_protocol
from calib.recording import Recording
from calib.result import CalibrationResult
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


def _filtered_noise(rng: np.random.Generator, n: int, sd: float) -> np.ndarray:
    """White noise through a 3-sample moving average (as a sensor's low-pass filter): per-sample sd ``sd``,
    autocorrelation 2/3 and 1/3 at lags 1 and 2, so means and integrals scatter 3x the variance white noise would."""
    e = rng.normal(0.0, sd, (n + 2, 3))
    return (e[2:] + e[1:-1] + e[:-2]) / np.sqrt(3.0)


def test_low_pass_filtered_gyro_noise_is_counted_in_the_fits_noise():
    """A gyro whose noise is correlated from sample to sample (its own filter): the rests' means and the motions'
    integrals scatter 3x the variance the per-sample spread says. Counted, the fit's chi-square matches its degrees
    of freedom (it would be 3x them otherwise, and read as physics left out) and the uncertainties stay honest."""
    z, birge = [], []
    for seed in range(20):
        rng = np.random.default_rng(900 + seed)
        rec, truth = simulate(seed, noise=1e-4, fs=100.0, script=multi_position_script(rng), accel_noise_g=0.005)
        noisy = Recording(rec.t, rec.gyro + _filtered_noise(rng, len(rec), 0.08), rec.accel, meta=rec.meta)
        res = calibrate_multi_position(noisy)
        z.append(np.concatenate([res.k - truth.k, res.b - truth.b]) / np.concatenate([res.k_std, res.b_std]))
        birge.append(res.quality["birge_ratio"])
    assert 0.85 < float(np.mean(np.square(birge))) < 1.2, birge
    sd = np.array(z).std(axis=0)
    assert np.all((sd > 0.5) & (sd < 1.5)), sd


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
    from calib.io.imu_tk import read_imu_tk

    rec = read_imu_tk(real_data / "imu_tk" / "xsens_gyro.mat", real_data / "imu_tk" / "xsens_acc.mat")
    res, protocol = calibrate_protocol(rec)
    assert protocol == "multi-position"
    q = res.quality
    assert q["constraints"] == {"rests": 38, "gravity_motions": 37, "full_turns": 0}
    assert len(q["gravity_residual_deg"]) == 37
    # each motion's end gravity carried back to its start, after calibration: 0.48 deg rms with g = K m + b,
    # 0.14 deg with the g-sensitivity the rests reveal (each rest's mean reading moves with its gravity)
    g = q["g_sensitivity"]
    assert g["fitted"] and g["p_value"] < 1e-20
    assert g["without"]["gravity_residual_rms_deg"] > 0.4 and g["without"]["birge_ratio"] > 4
    assert q["gravity_residual_rms_deg"] < 0.2 and q["birge_ratio"] < 2.5
    assert res.G is not None and np.abs(res.G).max() < 0.2  # (deg/s)/g: the size MEMS datasheets quote
    assert np.all(res.k_std < 0.002) and np.all(res.b_std < 0.02)


G_TRUE = np.array([[0.02, -0.06, 0.03], [0.08, 0.01, -0.04], [-0.05, 0.07, 0.02]])  # (deg/s)/g


def test_concealed_g_sensitivity_is_found_modelled_and_the_fit_improves():
    z = []
    for seed in range(8):
        rng = np.random.default_rng(900 + seed)
        rec, truth = simulate(seed, noise=0.05, fs=100.0, script=multi_position_script(rng), accel_noise_g=0.005,
                              effects=[GSensitivity(G_TRUE)])
        res = calibrate_multi_position(rec)
        plain = calibrate_multi_position(rec, g_sensitivity=False)
        g = res.quality["g_sensitivity"]
        assert g["fitted"] and g["p_value"] < 1e-6, g
        assert res.G is not None and res.G_std is not None
        z.append(((res.G - G_TRUE) / res.G_std).ravel())
        # the fit improves to the noise level, and the parameters with it
        assert g["without"]["birge_ratio"] > 5 and res.quality["birge_ratio"] < 1.2
        assert res.quality["gravity_residual_rms_deg"] < g["without"]["gravity_residual_rms_deg"] / 3
        assert np.abs(res.b - truth.b).max() < np.abs(plain.b - truth.b).max()
        assert np.all(np.abs(res.k - truth.k) < 4e-4) and np.all(np.abs(res.b - truth.b) < 4e-3)
    z_a = np.array(z)
    assert np.all(np.abs(z_a) < 5.0)
    assert 0.6 < z_a.std() < 1.4, z_a.std()  # honest uncertainty of G


def test_g_sensitivity_is_not_fitted_on_a_sensor_without_it_and_can_be_forced():
    for seed in range(6):
        rng = np.random.default_rng(700 + seed)
        rec, _ = simulate(seed, noise=0.05, fs=100.0, script=multi_position_script(rng), accel_noise_g=0.005)
        res = calibrate_multi_position(rec)
        g = res.quality["g_sensitivity"]
        assert not g["fitted"] and g["p_value"] > 1e-3 and "not significant" in g["reason"]
        assert res.G is None and "G" not in res.to_dict()
    forced = calibrate_multi_position(rec, g_sensitivity=True)
    assert forced.G is not None and np.all(np.abs(forced.G) < 5 * forced.G_std + 1e-9)
    assert forced.quality["g_sensitivity"]["reason"] == "asked for"


def test_g_sensitivity_is_kept_and_applied_by_the_result():
    rng = np.random.default_rng(901)
    rec, _ = simulate(1, noise=0.05, fs=100.0, script=multi_position_script(rng), accel_noise_g=0.005,
                      effects=[GSensitivity(G_TRUE)])
    res = calibrate_multi_position(rec)
    back = CalibrationResult.from_dict(res.to_dict())
    assert back.to_dict() == res.to_dict() and back.G is not None
    m, a = rec.gyro[:5], rec.accel[:5]
    corr = Correction.from_result(res)
    a_cal = (a - corr.o) @ corr.A.T  # the G term takes the calibrated specific force
    assert np.allclose(corr.apply(m, a)[0], (m - a_cal @ res.G.T) @ res.matrix.T + res.b)
    assert np.allclose(corr.apply(m)[0], m @ res.matrix.T + res.b)


def test_the_fit_jacobian_matches_finite_differences_with_the_g_sensitivity(monkeypatch: pytest.MonkeyPatch):
    import calib.estimators.multi_position.model as model
    from calib.estimators.multi_position.estimator import _data, motions_between_rests
    from calib.stages.detector import detect_stages

    rng = np.random.default_rng(902)
    rec, truth = simulate(2, noise=0.05, fs=100.0, script=multi_position_script(rng, n=8, first_rest_s=10.0),
                          accel_noise_g=0.005, effects=[GSensitivity(G_TRUE)])
    stills, motions = motions_between_rests(detect_stages(rec))
    data = _data(rec, stills, motions, np.zeros(9, dtype=bool))
    p = model.Params(np.diag(truth.k), truth.b, G_TRUE * 0.5, np.array([1, 1, 1, 0, 0, 0, 0, 0, 0], dtype=float))
    # the Gauss-Newton Jacobian leaves out the whitening's own dependence on the parameters: hold the re-orientations'
    # joint noise covariance at its value at p, so that what is compared is the Jacobian alone
    real = model.GravityTerms.covariance
    held: dict[str, np.ndarray] = {}

    def covariance_held_at_p(self: model.GravityTerms, *args: np.ndarray) -> np.ndarray:
        if "cov" not in held:
            held["cov"] = real(self, *args)
        return held["cov"]

    monkeypatch.setattr(model.GravityTerms, "covariance", covariance_held_at_p)
    _, jac = model.system(p, data)
    h = 1e-6
    for col in range(21):
        step = np.zeros(jac.shape[1])
        step[col] = h
        fd = (model.system(p.stepped(step, data.free_a), data)[0] - model.system(p.stepped(-step, data.free_a), data)[0]) / (2 * h)
        assert np.abs(jac[:, col] - fd).max() < 1e-6 * np.abs(fd).max(), col


def test_long_motions_far_from_the_starting_scale_factors_still_converge(real_data: Path):
    """imu_tk's Xsens reads 31 % low on every axis. With two of its rests taken out, two motions are joined into
    ones of 12-16 s that end tens of degrees off at the starting K = I: an undamped Gauss-Newton step overshot
    there and diverged (reported as 'the re-orientations do not determine K'); the damped fit converges to the
    same calibration."""
    from calib.io.imu_tk import read_imu_tk
    from calib.stages.detector import detect_stages

    rec = read_imu_tk(real_data / "imu_tk" / "xsens_gyro.mat", real_data / "imu_tk" / "xsens_acc.mat")
    stages = detect_stages(rec)
    stills = [s for s in stages if s.kind == "still"]
    fewer = [s for s in stages if s is not stills[10] and s is not stills[13]]
    full, joined = calibrate_multi_position(rec, stages), calibrate_multi_position(rec, fewer)
    assert joined.quality["constraints"]["gravity_motions"] == 35
    assert np.all(np.abs(joined.k - full.k) < 3 * full.k_std)


def test_re_orientations_no_calibration_explains_are_refused_with_what_to_check(ferraris_csv: Path):
    """imucal's session read at 10 Hz instead of 102.4: its stages then hold motions no gyro calibration makes
    agree with the accelerometer. The fit converges, 9 deg rms off, and that is refused rather than reported."""
    from calib.io.readers import read_recording

    with pytest.raises(CalibrationError, match=r"gravity is still \d+\.\d deg rms off.*Check the sample rate"):
        calibrate_protocol(read_recording(ferraris_csv, fs=10.0), "multi-position")


def test_re_orientations_far_beyond_a_g_sensitivity_are_refused_before_one_is_fitted(ferraris_csv: Path, monkeypatch):
    """Gravity 7 deg rms off without a g-sensitivity is more than one could take away (a few tenths): the refusal comes
    without the g-sensitivity's fit, a third of the work."""
    import calib.estimators.multi_position.estimator as mp
    from calib.io.readers import read_recording

    def not_to_be_fitted(*_: object) -> None:
        raise AssertionError("the g-sensitivity was fitted for re-orientations no calibration explains")

    monkeypatch.setattr(mp, "_g_sensitivity_choice", not_to_be_fitted)
    with pytest.raises(CalibrationError, match=r"gravity is still \d+\.\d deg rms off.*Check the sample rate"):
        calibrate_protocol(read_recording(ferraris_csv, fs=10.0), "multi-position")
