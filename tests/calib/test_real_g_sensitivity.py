"""A g-sensitivity put into real readings (imu_tk's Xsens session, 38 rests in as many orientations): each reading
gains G a, a the accelerometer's specific force, with all nine terms of G 0.05-0.1 (deg/s)/g, the size consumer
MEMS datasheets give. Before, one such G sent the calibration from the identity to a far minimum (gravity 23 deg rms
off) and the recording was refused as holding no full turn; and the diagnosis put the rests' differing zero-rate
outputs down to a scale asymmetry and a bias drift, because the wander re-estimated at the rests alone made the
model with G fit the re-orientations worse than the model without it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from calib.diagnosis import diagnose
from calib.pipeline import calibrate_protocol
from calib.recording import Recording


def _injected(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(0.05, 0.1, (3, 3)) * rng.choice([-1.0, 1.0], (3, 3))


@pytest.fixture
def session(imu_tk_session: Recording) -> Recording:
    return imu_tk_session


@pytest.mark.parametrize("seed", [0, 1])
def test_calibrate_finds_the_added_g_sensitivity_and_keeps_k(session: Recording, seed: int) -> None:
    whole, _ = calibrate_protocol(session)
    G = _injected(seed)
    assert session.accel is not None
    result, used = calibrate_protocol(dataclasses.replace(session, gyro=session.gyro + session.accel @ G.T))
    assert used == "multi-position"
    assert np.all(np.abs(result.k - whole.k) < 2.5 * whole.k_std), (result.k, whole.k)
    # the session's own g-sensitivity plus the one put in, to a tenth of the latter's size (a fifth asked)
    assert whole.G is not None and result.G is not None
    miss = np.asarray(result.G) - (np.asarray(whole.G) + G)
    assert np.linalg.norm(miss) < 0.2 * np.linalg.norm(G), (miss, G)


def test_diagnose_names_the_g_sensitivity(session: Recording, imu_tk_own_effects_20: frozenset[str]) -> None:
    assert session.accel is not None
    found = diagnose(dataclasses.replace(session, gyro=session.gyro + session.accel @ _injected(1).T), n_boot=20)
    named = [e["name"] for e in found.effects]
    assert "g_sensitivity" in named, named
    assert set(named) <= imu_tk_own_effects_20 | {"g_sensitivity"}, (named, imu_tk_own_effects_20)
