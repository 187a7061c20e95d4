"""A device still settling during its rests (rocking, easing into place): the multi-position fit counts each rest's
measured drift in its noise, and says which rests were settling."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import calib.estimators.multi_position.model as model
from calib.estimators.multi_position.estimator import calibrate_multi_position
from calib.simulator import simulate
from calib.simulator.lab_scripts import multi_position_script
from calib.simulator.protocol import Motion, ProtocolScript, Still

SETTLING = (5, 12, 20, 28)  # rests (counted from the first) in which the device tilts


def _settling_script(rng: np.random.Generator, tilt_deg: float = 0.3) -> ProtocolScript:
    """imu_tk's protocol with a slow tilt of ``tilt_deg`` over 3 s inside some 5 s rests: 0.1 deg/s, which the
    stage detector still counts as rest."""
    segs, rest = [], 0
    for seg in multi_position_script(rng).segments:
        if isinstance(seg, Still) and rest > 0 and rest in SETTLING:
            axis = rng.standard_normal(3)
            segs += [Still(1.0), Motion(tuple(tilt_deg * axis / np.linalg.norm(axis)), duration_s=3.0), Still(1.0)]
        else:
            segs.append(seg)
        rest += isinstance(seg, Still)
    return ProtocolScript(tuple(segs))


def test_settling_rests_are_found_counted_and_the_fit_stays_honest(monkeypatch: pytest.MonkeyPatch):
    z, found = [], 0
    for seed in range(6):
        rng = np.random.default_rng(300 + seed)
        rec, truth = simulate(seed, noise=0.05, fs=100.0, script=_settling_script(rng), accel_noise_g=0.005)
        res = calibrate_multi_position(rec)
        settling = res.quality["settling"]
        counted = set(settling["rests_counted"])
        assert counted <= set(SETTLING), counted  # a quiet rest is counted one time in a thousand
        assert len(settling["drift_deg"]) == 37
        found += len(counted)
        fits = res.quality["constraint_fit"]
        assert sum(f["expected"] for f in fits.values()) == pytest.approx(res.quality["dof"])  # the parameters' share
        if counted != set(SETTLING):
            # a tilt about gravity itself: the accelerometer cannot see it; the gyro's rest means do (the rests' group)
            assert fits["rests"]["ratio"] > 3.0 and fits["motions"]["ratio"] < 1.6, fits
            continue
        assert res.quality["birge_ratio"] < 1.25
        assert all(0.5 < f["ratio"] < 1.6 for f in fits.values()), fits
        z.append(np.concatenate([res.k - truth.k, res.b - truth.b]) / np.concatenate([res.k_std, res.b_std]))
        with monkeypatch.context() as m:  # the same recording, settling left out of the noise
            m.setattr(model, "SETTLE_SHARE", 0.0)
            left_out = calibrate_multi_position(rec).quality
            assert left_out["birge_ratio"] > 1.5
            assert left_out["constraint_fit"]["motions"]["ratio"] > 3.0 and left_out["constraint_fit"]["rests"]["ratio"] > 5.0
    assert found >= 20 and len(z) >= 4, (found, len(z))
    assert np.all(np.abs(np.array(z)) < 4.0)


def test_imu_tk_rests_that_settle_are_named_and_counted(real_data: Path):
    from calib.io.imu_tk import read_imu_tk

    rec = read_imu_tk(real_data / "imu_tk" / "xsens_gyro.mat", real_data / "imu_tk" / "xsens_acc.mat")
    res = calibrate_multi_position(rec)
    settling = res.quality["settling"]
    # the rest at 207.9-211.6 s tilts by 0.16 deg within itself (its accelerometer and gyro both scatter more)
    assert 13 in settling["rests_counted"] and settling["largest_deg"] == pytest.approx(0.157, abs=0.01)
    assert len(res.stages) > 0 and res.quality["birge_ratio"] < 1.4
    fits = res.quality["constraint_fit"]  # |a| = 1 g is the kind least explained by the noise; the re-orientations are at it
    assert fits["accelerometer_magnitude"]["ratio"] > fits["rests"]["ratio"] > fits["motions"]["ratio"]
    assert fits["motions"]["p_value"] > 0.1
