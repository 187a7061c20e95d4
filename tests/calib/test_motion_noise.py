"""The gyroscope's noise while moving (``calib.noise.motion``): measured in the top of the band against the rests',
counted where beyond chance, shown on a concealed simulated effect and on imu_tk's Xsens."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calib.effects import MotionNoise, SimulationConfigError, parse_effect
from calib.estimators.multi_position.estimator import calibrate_multi_position
from calib.noise.motion import MOTION_NOISE_ALPHA, motion_noise, no_motion_noise
from calib.simulator import simulate
from calib.simulator.lab_scripts import multi_position_script

FS = 100.0
RESTS = [(0, 5000)] + [(5300 + 800 * i, 5300 + 800 * i + 500) for i in range(30)]  # a 50 s rest, then 5 s rests
MOTIONS = [(5000 + 800 * i, 5300 + 800 * i) for i in range(30)]  # 3 s motions between them


def _gyro(rng: np.random.Generator, ratio: np.ndarray, n: int = 5000 + 800 * 30) -> np.ndarray:
    """White noise of 0.1 deg/s, ``ratio`` times its variance in the motions, under a slow 'hand' motion there."""
    g = 0.1 * rng.standard_normal((n, 3))
    t = np.arange(300) / FS
    for i, j in MOTIONS:
        g[i:j] *= np.sqrt(ratio)
        g[i:j] += 90.0 * np.sin(np.pi * t / 3.0)[:, None] ** 2 * np.array([1.0, -0.5, 0.3])  # all below 1 Hz
    return g


def test_white_noise_shows_motion_noise_only_as_often_as_its_false_positive_rate():
    rng = np.random.default_rng(11)
    counted = np.array([motion_noise(_gyro(rng, np.ones(3)), RESTS, MOTIONS, FS).counted for _ in range(200)])
    assert np.mean(counted != 1.0) < 2.5 * MOTION_NOISE_ALPHA


def test_motion_noise_is_measured_axis_by_axis():
    rng = np.random.default_rng(12)
    truth = np.array([1.0, 1.5, 2.5])
    found = motion_noise(_gyro(rng, truth), RESTS, MOTIONS, FS)
    assert found.measured and found.ratio is not None and found.p_value is not None
    assert found.ratio == pytest.approx(truth, rel=0.12)
    assert found.counted[0] == 1.0 and found.counted[1:] == pytest.approx(found.ratio[1:])
    assert found.p_value[1] < 1e-6 and found.band_hz == pytest.approx((45.0, 50.0))
    assert found.to_dict()["counted"] == [float(v) for v in found.counted]


def test_a_sample_rate_whose_top_band_holds_the_hand_leaves_it_unmeasured():
    rng = np.random.default_rng(15)
    found = motion_noise(_gyro(rng, np.full(3, 2.0)), RESTS, MOTIONS, 50.0)
    assert not found.measured and "89 Hz or more" in found.to_dict()["reason"]


def test_too_few_samples_leave_it_unmeasured():
    rng = np.random.default_rng(13)
    found = motion_noise(_gyro(rng, np.full(3, 2.0)), RESTS, MOTIONS[:1], FS)
    assert not found.measured and list(found.counted) == [1.0, 1.0, 1.0]
    assert "1000 samples" in found.to_dict()["reason"]


def test_the_effect_is_parsed_and_checked():
    assert np.allclose(parse_effect("motion_noise", "2").ratio, 2.0)
    e = parse_effect("motion-noise", "1.5,2,2.5,10")
    assert isinstance(e, MotionNoise) and np.allclose(e.ratio, [1.5, 2.0, 2.5]) and e.threshold_dps == 10.0
    with pytest.raises(SimulationConfigError, match="at least 1"):
        parse_effect("motion_noise", "0.5")
    with pytest.raises(SimulationConfigError, match="motion_noise"):
        parse_effect("motion_noise", "1,2,3,4,5")


def test_a_concealed_motion_noise_is_found_and_counted():
    """A gyro twice as noisy while turning, with an accelerometer quiet enough that the gyro's noise rules the
    re-orientations' residuals: measured (diluted by the motions' slow ends, below the effect's threshold),
    and counted, the re-orientations are back at their noise and the scale factors' uncertainty honest."""
    rng = np.random.default_rng([9, 0])
    rec, truth = simulate(30_000, noise=0.15, fs=FS, script=multi_position_script(rng), accel_noise_g=0.001,
                          effects=[MotionNoise(np.full(3, 2.3))])
    res = calibrate_multi_position(rec)
    moving = res.quality["gyro_motion_noise"]
    assert moving["measured"] and all(1.7 < r < 2.4 for r in moving["variance_ratio"])
    assert moving["counted"] == moving["variance_ratio"]
    plain = calibrate_multi_position(rec, motion_noise=False)
    assert plain.quality["gyro_motion_noise"] == no_motion_noise(FS, "not asked for").to_dict()
    with_it, without = res.quality["constraint_fit"]["motions"]["ratio"], plain.quality["constraint_fit"]["motions"]["ratio"]
    assert without > 1.6 and with_it < 1.25
    assert np.max(np.abs(res.k - truth.k) / res.k_std) < 3.5


def test_imu_tk_gyro_is_noisier_while_moving(real_data: Path):
    """Xsens' gyro carries 1.2-1.8 times its rest noise variance at 45-50 Hz while the hand turns it (its knocks left
    out: with them, 1.2-2.1); counted, the re-orientations' gravity residuals are at their noise (chi-square ratio
    1.07), where they were 1.5 times it."""
    from calib.io.imu_tk import read_imu_tk

    rec = read_imu_tk(real_data / "imu_tk" / "xsens_gyro.mat", real_data / "imu_tk" / "xsens_acc.mat")
    res = calibrate_multi_position(rec)
    moving = res.quality["gyro_motion_noise"]
    assert moving["measured"] and moving["variance_ratio"] == pytest.approx([1.26, 1.84, 1.24], abs=0.02)
    assert max(moving["p_value"]) < 1e-6
    motions = res.quality["constraint_fit"]["motions"]
    assert 0.85 < motions["ratio"] < 1.15 and motions["p_value"] > 0.1
    plain = calibrate_multi_position(rec, motion_noise=False).quality["constraint_fit"]["motions"]
    assert plain["ratio"] > 1.4 and plain["p_value"] < 0.01


def test_a_sensor_filter_that_empties_the_top_band_leaves_it_unmeasured():
    """Behind a low-pass filter at half the Nyquist frequency the top band holds next to nothing of the noise that is
    integrated: a ratio of what is left there would say nothing about it."""
    from scipy.signal import butter, sosfiltfilt

    rng = np.random.default_rng(14)
    filtered = sosfiltfilt(butter(6, 0.5, output="sos"), _gyro(rng, np.full(3, 2.0)), axis=0)
    assert not motion_noise(filtered, RESTS, MOTIONS, FS).measured
    assert motion_noise(_gyro(rng, np.full(3, 2.0)), RESTS, MOTIONS, FS).measured
