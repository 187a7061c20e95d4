"""The null is simulated with the recording's own noise colour: a real gyroscope's readings pass its low-pass filter, so
neighbouring samples are correlated, and a white null at the measured level took that colour for an effect."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.signal import butter, lfilter

from calib.diagnosis import diagnose
from calib.diagnosis.data import make_layout
from calib.diagnosis.null import noise_colour
from calib.simulator import simulate
from calib.stages.detector import detect_stages


def _low_passed(seed: int, sd: float):
    """A protocol recording whose only noise is white noise through a second-order low-pass at 0.4 of Nyquist (21 Hz
    at 104 Hz), as a sensor's filter gives, at ``sd`` deg/s."""
    rec, _ = simulate(seed, noise=0.0)
    b, a = butter(2, 0.4)
    x = lfilter(b, a, np.random.default_rng(100 + seed).standard_normal((len(rec), 3)), axis=0)
    return dataclasses.replace(rec, gyro=rec.gyro + x / x.std(axis=0) * sd)


def test_the_noise_model_is_the_recordings_own() -> None:
    """An AR(2) noise at the rests is found with its coefficients; white noise stays white (order 0)."""
    rec, _ = simulate(1, noise=0.0)
    layout = make_layout(rec, detect_stages(rec))
    rng = np.random.default_rng(7)
    phi = np.array([0.6, -0.3])
    e = rng.standard_normal((len(rec), 3)) * 0.04
    ar = lfilter([1.0], [1.0, *(-phi)], e, axis=0)
    model = noise_colour(layout, ar)
    assert model is not None and model.order >= 2
    np.testing.assert_allclose(model.phi[:, :2], np.tile(phi, (3, 1)), atol=0.08)
    np.testing.assert_allclose(model.innovation, 0.04, rtol=0.1)
    white = noise_colour(layout, rng.standard_normal((len(rec), 3)) * 0.04)
    assert white is not None and white.order == 0
    # drawn paths have the model's lag-one correlation (phi1 / (1 - phi2) for an AR(2))
    paths = model.draw(np.random.default_rng(3), 4, 20_000)
    lag1 = np.mean([np.corrcoef(p[:-1, 0], p[1:, 0])[0, 1] for p in paths])
    assert lag1 == pytest.approx(model.phi[0, 0] / (1 - model.phi[0, 1]), abs=0.03)


@pytest.mark.parametrize("seed", [2, 4, 6, 7])
def test_a_sensors_filtered_noise_is_not_named_as_an_effect(seed: int) -> None:
    """Readings with nothing but filtered noise (0.05 deg/s): nothing named. With a white null of the same level a
    wandering bias or a misalignment was named in each of these recordings."""
    found = diagnose(_low_passed(seed, 0.05), n_boot=200)
    assert [e["name"] for e in found.effects] == []
