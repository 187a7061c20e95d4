"""Accelerometer calibration from rests: recovery, honest uncertainty, identification, and imu_tk's real session."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calib.estimators.accel import AccelCalibration, AccelCalibrationError, fit_accelerometer
from calib.io.imu_tk import read_imu_tk


def _rests(rng: np.random.Generator, n: int, scale, offset, mis, sd_g: float, planar: bool = False) -> np.ndarray:
    """Mean readings of n rests: gravity in random orientations through the inverse model, plus noise."""
    g = rng.standard_normal((n, 3))
    if planar:
        g[:, 2] = 0.0  # every rest with z horizontal: z's scale and offset are not seen
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    M = AccelCalibration(scale=np.asarray(scale, dtype=float), offset=np.zeros(3), misalignment=np.asarray(mis, dtype=float)).matrix
    return np.linalg.solve(M, g.T).T + offset + rng.normal(0.0, sd_g, (n, 3))


TRUTH = (np.array([1.02, 0.97, 1.01]), np.array([0.03, -0.05, 0.02]), np.array([0.004, -0.006, 0.002]))


def test_recovers_the_nine_parameters_with_honest_uncertainty():
    rng = np.random.default_rng(0)
    z = []
    for _ in range(300):
        cal = fit_accelerometer(_rests(rng, 37, *TRUTH, sd_g=0.001))
        est = np.concatenate([cal.scale, cal.offset, cal.misalignment])
        std = np.concatenate([cal.scale_std, cal.offset_std, cal.misalignment_std])
        z.append((est - np.concatenate(TRUTH)) / std)
    z = np.array(z)
    assert np.all(np.abs(z.mean(axis=0)) < 0.25), z.mean(axis=0)
    sd = z.std(axis=0)
    assert np.all((sd > 0.8) & (sd < 1.25)), sd


def test_applying_the_calibration_puts_every_rest_at_one_g():
    rng = np.random.default_rng(1)
    means = _rests(rng, 30, *TRUTH, sd_g=0.0005)
    cal = fit_accelerometer(means)
    assert np.abs(np.linalg.norm(cal.apply(means), axis=1) - 1.0).max() < 0.003
    assert cal.residual_rms_g < 0.002 and cal.identified == ("s_x", "s_y", "s_z", "o_x", "o_y", "o_z", "a_yz", "a_zy", "a_zx")


def test_too_few_rests_fall_back_to_fewer_parameters_and_say_so():
    rng = np.random.default_rng(2)
    cal = fit_accelerometer(_rests(rng, 10, TRUTH[0], TRUTH[1], np.zeros(3), sd_g=0.0005))
    assert cal.identified == ("s_x", "s_y", "s_z", "o_x", "o_y", "o_z")
    assert cal.misalignment_std is None and "the misalignment (12 rests needed, 10 given)" in cal.note
    with pytest.raises(AccelCalibrationError, match="at least 4 rests"):
        fit_accelerometer(_rests(rng, 3, *TRUTH, sd_g=0.001))


def test_rests_that_never_turn_an_axis_vertical_cannot_give_its_scale():
    rng = np.random.default_rng(3)
    cal = fit_accelerometer(_rests(rng, 20, np.ones(3), np.zeros(3), np.zeros(3), sd_g=0.0005, planar=True))
    assert "s_z" not in cal.identified and "o_z" not in cal.identified and "z axis never pointed" in cal.note
    assert cal.scale[2] == 1.0 and np.all(np.abs(cal.scale[:2] - 1) < 0.01)


def test_imu_tk_xsens_session_accelerometer_to_a_tenth_of_a_milli_g(real_data: Path):
    from calib.estimators.accel import calibrate_accelerometer
    from calib.stages.detector import detect_stages

    rec = read_imu_tk(real_data / "imu_tk" / "xsens_gyro.mat", real_data / "imu_tk" / "xsens_acc.mat")
    assert len(rec) == 51175 and rec.fs == pytest.approx(100.01, abs=1e-3)  # the Xsens's own rate
    cal = calibrate_accelerometer(rec, detect_stages(rec))
    assert cal.n_rests == 38  # the initial rest and the 37 between the re-orientations
    assert len(cal.identified) == 9
    assert cal.residual_rms_g < 2e-4  # from 129 mg with the nominal sensitivity
    assert np.all(np.abs(cal.scale - 0.917) < 0.01)  # the nominal 3724 counts/g is about 9 % off


@pytest.mark.parametrize("seed", range(5))
def test_the_fit_s_jacobian_is_the_derivative_of_its_residuals(seed: int) -> None:
    """The accelerometer fit's analytic Jacobian (every plan's parameters) against central differences."""
    from scipy.optimize._numdiff import approx_derivative

    from calib.estimators import accel

    rng = np.random.default_rng(seed)
    means = rng.normal(size=(14, 3))
    means = means / np.linalg.norm(means, axis=1, keepdims=True) * rng.uniform(0.95, 1.05, 3) + rng.normal(0, 0.02, 3)
    for free in (np.ones(9, bool), np.r_[np.ones(6, bool), np.zeros(3, bool)], np.r_[np.zeros(3, bool), np.ones(3, bool),
                                                                                    np.zeros(3, bool)]):
        x = (accel.NOMINAL + rng.normal(0, 0.02, 9))[free]
        numeric = approx_derivative(lambda v, f=free: accel._residuals(v, f, means), x, method="3-point")
        np.testing.assert_allclose(accel._jacobian(x, free, means), numeric, atol=1e-8)


def test_imucal_s_rests_are_fitted_without_wandering_along_what_they_do_not_determine(real_data: Path) -> None:
    """imucal's session's 13 rests lie in six orientations (each face down, some twice), which do not determine the
    misalignment: its nine-parameter fit wandered for 900 evaluations (94 % of the calibration's time) before the
    six-parameter one was taken, then for MAX_EVALUATIONS; now it is not tried, and the note says why. The same
    result."""
    from calib.estimators import accel
    from calib.io.readers import read_recording
    from calib.pipeline import protocol_stages

    rec = read_recording(real_data / "imucal" / "example_ferraris_session.csv", fs=102.4)
    stages, _found, _used = protocol_stages(rec, "auto", rec.meta.sections, None)
    means = accel.rest_means(rec, [s for s in stages if s.kind == "still"])
    calls = [0]
    residuals = accel._residuals

    def counted(*args: object) -> np.ndarray:
        calls[0] += 1
        return residuals(*args)  # type: ignore[arg-type]

    accel._residuals = counted  # type: ignore[assignment]
    try:
        cal = fit_accelerometer(means)
    finally:
        accel._residuals = residuals  # type: ignore[assignment]
    assert cal.identified == accel.PARAMS[:6]  # the misalignment held, as before
    assert "the misalignment (rests in 9 different orientations needed, 6 given)" in cal.note
    assert calls[0] < accel.MAX_EVALUATIONS, calls[0]  # only the six-parameter fit, converged in a few steps
    assert cal.residual_rms_g < 1e-3


def test_a_pose_rested_in_twice_counts_as_one_orientation() -> None:
    """Six poses (each face down), each rested in twice with a hand's few degrees of difference: 12 rests, enough
    by number for all nine parameters, but six orientations, so the misalignment is held and the note says why."""
    from calib.estimators import accel

    rng = np.random.default_rng(7)
    faces = np.vstack([np.eye(3), -np.eye(3)])
    g = np.repeat(faces, 2, axis=0) + rng.normal(0.0, 0.03, (12, 3))  # about 2 degrees apart
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    assert accel.distinct_orientations(g) == 6
    assert accel.distinct_orientations(np.vstack([g, rng.normal(size=(4, 3))])) >= 9
    M = AccelCalibration(scale=TRUTH[0], offset=np.zeros(3), misalignment=np.zeros(3)).matrix
    cal = fit_accelerometer(np.linalg.solve(M, g.T).T + TRUTH[1] + rng.normal(0.0, 3e-4, (12, 3)))
    assert cal.identified == accel.PARAMS[:6] and "6 given" in cal.note
    np.testing.assert_allclose(cal.scale, TRUTH[0], atol=5e-3)
