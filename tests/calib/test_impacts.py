"""Knocks (calib.effects.impacts): a device put down by hand rings briefly. The knock turns it by nothing; the rests'
statistics and the motions' noise in the top of the band leave it out, so one knock does not widen every rest's and
every motion's noise, and the reported uncertainty stays the spread of the errors."""

from __future__ import annotations

import numpy as np
import pytest

from calib.effects import Impacts, parse_effect
from calib.effects.base import SimulationConfigError
from calib.estimators.multi_position.estimator import calibrate_multi_position
from calib.noise.rests import still_statistics
from calib.simulator import simulate
from calib.simulator.lab_scripts import multi_position_script
from calib.stages.detector import detect_stages


def test_a_knock_rings_where_the_device_is_put_down_and_turns_it_by_nothing() -> None:
    quiet, truth = simulate(3, noise=0.0)
    knocked, _ = simulate(3, noise=0.0, effects=[Impacts(peak_dps=20.0)])
    ring = knocked.gyro - quiet.gyro
    size = np.linalg.norm(ring, axis=1)
    assert 8.0 < size.max() <= 20.0  # up to the peak (sampled at 104 Hz, a 30 Hz ring shows most of it)
    dt = np.diff(knocked.t, append=knocked.t[-1])
    net = np.abs(np.cumsum(ring * dt[:, None], axis=0)).max()
    assert net < 0.12  # at most the ring's own angle (peak / 2 pi f = 0.1 deg) partway, never a rotation left over
    assert np.abs((ring * dt[:, None]).sum(axis=0)).max() < 1e-9
    ends = [s.end for s in truth.stages if s.kind == "turn"]
    for e in ends:
        assert size[e - 3 : e + 12].max() > 5.0  # each turn's end is put down with a knock
    assert parse_effect("impacts", "25,40,0.01") == Impacts(25.0, 40.0, 0.01)
    with pytest.raises(SimulationConfigError):
        parse_effect("impacts", "25,40,3")


def test_a_knock_in_a_rest_does_not_widen_the_noise() -> None:
    rng = np.random.default_rng(4)
    gyro = rng.normal(0.0, 0.05, (1, 3000, 3))
    bounds = np.array([[[0, 1000], [1200, 3000]]])
    clean_mean, clean_n, clean_sigma = still_statistics(gyro, bounds)
    knocked = gyro.copy()
    t = np.arange(12) / 100.0
    knocked[0, 1200:1212] += (20.0 * np.exp(-t / 0.02) * np.cos(2 * np.pi * 30 * t))[:, None] * np.array([0.6, 0.0, 0.8])
    mean, count, sigma = still_statistics(knocked, bounds)
    np.testing.assert_allclose(sigma, clean_sigma, rtol=0.03)
    np.testing.assert_allclose(mean, clean_mean, atol=3 * 0.05 / np.sqrt(1800))
    assert clean_n[0, 1] - 40 < count[0, 1] < clean_n[0, 1]  # the knock and its ring left out, no more


def test_knocks_at_every_put_down_leave_a_multi_position_calibrations_uncertainty_honest() -> None:
    z, ratios = [], []
    for seed in range(12):
        rng = np.random.default_rng(700 + seed)
        rec, truth = simulate(seed, noise=0.05, fs=100.0, script=multi_position_script(rng), accel_noise_g=0.005,
                              effects=[Impacts()])
        res = calibrate_multi_position(rec, detect_stages(rec))
        z.append(np.concatenate([res.k - truth.k, res.b - truth.b]) / np.concatenate([res.k_std, res.b_std]))
        ratios.append(res.quality["gyro_motion_noise"]["variance_ratio"])
        assert np.allclose(res.noise_dps, 0.05, rtol=0.1)
    assert np.all(np.array(ratios) < 1.3), ratios  # the knocks are not read as the motions' noise (they were 60-95x)
    spread = float(np.std(np.array(z)))
    assert 0.8 < spread < 1.25, spread  # the reported std within 1.25x of the errors' spread
