"""How much more the rests' means scatter than their readings' spread says (calib.noise.rests.noise_colour): 1 for
white noise, 3 for a 3-sample low-pass filter, 4 / (11/16) for a channel linearly interpolated onto four times its
own rate (Polar's 52 Hz accelerometer onto its 208 Hz gyroscope), and a knock in a rest does not count as colour.
The placement tilts measured from such an accelerometer say how well they are known, and so do the calibration and
the diagnosis."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calib.diagnosis.data import build_problem, make_layout
from calib.noise.rests import INTERPOLATED_LAGS, noise_colour
from calib.pipeline import calibrate
from calib.recording import Recording
from calib.simulator import simulate
from calib.stages.placement import measure_tilts

SPANS = [(0, 4000), (4500, 9000), (9100, 12000)]


def _filtered_noise(rng: np.random.Generator, n: int, sd: float) -> np.ndarray:
    """White noise through a 3-sample moving average (as a sensor's low-pass filter): per-sample sd ``sd``,
    autocorrelation 2/3 and 1/3 at lags 1 and 2, so means and integrals scatter 3x the variance white noise would."""
    e = rng.normal(0.0, sd, (n + 2, 3))
    return (e[2:] + e[1:-1] + e[:-2]) / np.sqrt(3.0)


def _from_quarter_rate(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``x`` (n, 3) as a channel at a quarter of the rate, interpolated back onto ``t``."""
    slow = np.arange(0, len(t), 4)
    return np.column_stack([np.interp(t, t[slow], x[slow, k]) for k in range(3)])


def test_noise_colour_is_one_for_white_noise_and_counts_a_low_pass_filters_correlation() -> None:
    rng = np.random.default_rng(7)
    white = rng.normal(0.0, 0.1, (12000, 3))
    np.testing.assert_allclose(noise_colour(white, SPANS), 1.0, atol=0.08)
    filtered = _filtered_noise(rng, 12000, 0.1) + np.array([5.0, -3.0, 0.0]) * (np.arange(12000) >= 4500)[:, None]
    np.testing.assert_allclose(noise_colour(filtered, SPANS), 3.0, atol=0.25)  # the step between rests is not noise


def test_an_interpolated_channel_counts_as_the_readings_it_was_made_from() -> None:
    # linear interpolation at a quarter step: a reading's variance averages 11/16 of the source's, while a long mean
    # scatters as the source's over a quarter of the samples: 4 / (11/16) = 5.82 times what white noise would
    rng = np.random.default_rng(11)
    t = np.arange(12000) / 208.0
    slow = _from_quarter_rate(t, rng.normal(0.0, 0.002, (12000, 3)))
    np.testing.assert_allclose(noise_colour(slow, SPANS, max_lag=INTERPOLATED_LAGS), 4 / (11 / 16), rtol=0.08)
    assert np.all(noise_colour(slow, SPANS) < 5.3)  # three lags see the filter's reach, not an interpolation's


def test_a_knock_in_a_rest_is_not_colour() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(0.0, 0.1, (12000, 3))
    x[2000:2012] += np.array([4.0, -3.0, 2.0]) * np.hanning(12)[:, None] * 20  # a device put down hard, ringing
    np.testing.assert_allclose(noise_colour(x, SPANS), 1.0, atol=0.08)


def _interpolated_accel(rec: Recording) -> Recording:
    assert rec.accel is not None
    return replace(rec, accel=_from_quarter_rate(rec.t, rec.accel))


def test_a_tilt_from_an_interpolated_accelerometer_is_known_as_well_as_its_own_readings_allow() -> None:
    # the same rests read by an accelerometer at a quarter of the gyroscope's rate know each tilt half as well: the
    # interpolated samples between its readings add nothing (counted as readings, they claimed 0.83x the full rate's sd)
    rec, truth = simulate(5, noise=0.03, fs=208.0)
    turns = [s for s in truth.stages if s.kind == "turn"]
    stills = [s for s in truth.stages if s.kind == "still"]
    full = measure_tilts(rec, turns, stills, list(truth.stages)).sd_deg
    slow = measure_tilts(_interpolated_accel(rec), turns, stills, list(truth.stages)).sd_deg
    np.testing.assert_allclose(slow / full, 2.0, rtol=0.12)


def test_the_diagnosis_knows_a_tilt_from_an_interpolated_accelerometer_as_the_calibration_does() -> None:
    # the diagnosis weighs each turn's tilt by its sd: taken as white, Polar's interpolated readings weighed their
    # tilts 2.4 times too heavily against the closures (its replays simulate the colour, so only the fit suffered)
    rec, truth = simulate(5, noise=0.03, fs=208.0)
    stages = list(truth.stages)

    def tilt_sd(r: Recording) -> np.ndarray:
        assert r.accel is not None
        return build_problem(make_layout(r, stages), r.gyro[None], r.accel[None]).tilts().sd[0]

    np.testing.assert_allclose(tilt_sd(_interpolated_accel(rec)) / tilt_sd(rec), 2.0, rtol=0.12)
    # replays read in one pass: each recording's colour its own
    mixed = np.stack([rec.accel, _interpolated_accel(rec).accel])
    sd = build_problem(make_layout(rec, stages), np.stack([rec.gyro] * 2), mixed).tilts().sd
    np.testing.assert_allclose(sd[1] / sd[0], 2.0, rtol=0.12)


def test_k_from_an_interpolated_accelerometer_is_as_uncertain_as_it_says() -> None:
    # 40 simulated sessions at 208 Hz, the accelerometer at 52 Hz interpolated onto it (Polar Verity Sense): k_x and
    # k_y, set by the placement tilts, within their standard errors (error/std rms was 1.36 when every interpolated
    # sample counted as a reading)
    z = []
    for seed in range(1, 41):
        rec, truth = simulate(seed, noise=0.03, fs=208.0)
        res = calibrate(_interpolated_accel(rec))
        z.append(((res.k - truth.k) / res.k_std)[:2])
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.75 < rms < 1.2, rms


def test_a_filtered_gyroscopes_closures_fit_as_its_noise_says() -> None:
    # a gyroscope whose own filter smooths its readings (a 3-sample moving average: rests' means and turns' angles
    # scatter 3x the variance the per-sample spread says): counted, the closure fit's chi-square matches its degrees
    # of freedom (2.9x them otherwise, read as physics the model left out) and the errors their standard errors
    chi2, z = [], []
    for seed in range(40):
        rec, truth = simulate(seed, noise=0.0)
        e = np.random.default_rng(100 + seed).normal(0.0, 0.1, (len(rec) + 2, 3))
        filtered = Recording(rec.t, rec.gyro + (e[2:] + e[1:-1] + e[:-2]) / np.sqrt(3.0), rec.accel, rec.seq, meta=rec.meta)
        res = calibrate(filtered, method="closure")
        chi2.append(res.residuals["chi2"] / res.residuals["dof"])
        z.append(np.concatenate(((res.k - truth.k) / res.k_std, (res.b - truth.b) / res.b_std)))
        assert res.noise_dps is not None and np.allclose(res.noise_dps, 0.1, rtol=0.1)  # the readings' own spread
    assert 0.8 < float(np.mean(chi2)) < 1.25, np.mean(chi2)
    rms = np.sqrt(np.mean(np.square(z), axis=0))
    assert np.all((rms > 0.7) & (rms < 1.3)), rms
