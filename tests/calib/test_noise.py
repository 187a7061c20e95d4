"""Noise from a long rest (calib.noise.analysis): the Allan curve against closed forms, the readings and their
intervals, refusals, and `gyrocal noise` with its plot."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from calib.cli.main import main
from calib.errors import Refusal
from calib.io.readers import write_native_csv
from calib.noise.analysis import noise
from calib.noise.terms import B_FACTOR
from calib.simulator.rest_noise import RestNoise, simulate_rest

FS = 100.0


def test_the_simulated_noises_have_the_closed_form_allan_variance() -> None:
    """The simulator's white noise, random walk and Gauss-Markov bias against their closed forms, averaged over 40
    hours' curves (each point's mean within 3 of its standard errors)."""
    truth = RestNoise(density=0.01, random_walk=2e-4, gm_sigma=0.01, gm_tc_s=30.0)
    curves = np.array([noise(simulate_rest(seed, 1800.0, FS, truth)).gyro[0].curve.avar for seed in range(40)])
    tau = noise(simulate_rest(0, 1800.0, FS, truth)).gyro[0].curve.tau_s
    mean, sem = curves.mean(axis=0), curves.std(axis=0, ddof=1) / np.sqrt(len(curves))
    assert np.all(np.abs(mean - truth.avar(tau)) < 3 * sem + 0.02 * truth.avar(tau)), (mean / truth.avar(tau)).round(3)


def test_the_exact_degrees_of_freedom_are_sp1065s_for_white_noise_greenhalls_for_a_walk_and_mix_between_bounds() -> None:
    import allantools

    from calib.noise.allan import white_walk_edf

    n = 360_000
    for m in (4, 64, 1024, 8192):
        assert white_walk_edf(m, n, 1.0, 0.0) == pytest.approx(allantools.edf_simple(n + 1, m, 0), rel=5e-3)
        walk = white_walk_edf(m, n, 0.0, 1.0)
        assert walk == pytest.approx(allantools.edf_greenhall(-2, 2, m, n + 1, overlapping=True), rel=0.06)
        mixed = white_walk_edf(m, n, 0.5, 0.5)
        white = white_walk_edf(m, n, 1.0, 0.0)
        cauchy_schwarz = 1 / (0.5 / np.sqrt(white) + 0.5 / np.sqrt(walk)) ** 2  # the cross term at its largest
        independent = 1 / (0.25 / white + 0.25 / walk)  # the cross term left out
        assert cauchy_schwarz < mixed < independent


def test_white_noise_reads_its_density_within_its_interval_and_shows_no_floor_or_walk() -> None:
    truth = RestNoise(density=0.01)
    report = noise(simulate_rest(7, 1800.0, FS, truth, RestNoise(density=1e-4)))
    for a in (*report.gyro,):
        assert a.density.seen and a.density.lo95 <= truth.density <= a.density.hi95
        assert abs(a.density.value / truth.density - 1) < 0.05
        assert not a.bias_instability.seen and not a.random_walk.seen  # bounds only
        assert a.random_walk.hi95 < 3e-4 and a.bias_instability.hi95 < 2e-3  # a walk of 3e-4 would show
    assert all(abs(a.density.value / 1e-4 - 1) < 0.05 for a in report.accel)


def test_a_random_walk_is_read_on_its_rising_slope_and_the_floor_between() -> None:
    truth = RestNoise(density=0.01, random_walk=4e-4)
    report = noise(simulate_rest(3, 3600.0, FS, truth))
    tau = report.gyro[0].curve.tau_s
    floor = np.sqrt(truth.avar(tau))
    walks = [a.random_walk for a in report.gyro if a.random_walk.seen]
    assert len(walks) >= 2  # a long Gauss-Markov term may take the rise on an axis: then K is bounded, not read
    for k in walks:
        assert k.lo95 <= truth.random_walk <= k.hi95
        assert k.tau_range_s[1] == pytest.approx(tau[-1])  # dominant at the longest averaging times
    floors = [a.bias_instability for a in report.gyro if a.bias_instability.seen]
    assert len(floors) >= 2  # the floor is seen where the curve rises out of it beyond both bands
    for b in floors:
        assert b.value == pytest.approx(floor.min() / B_FACTOR, rel=0.35)


def test_the_intervals_hold_the_truth_about_as_often_as_they_say() -> None:
    """60 axes of white noise with a random walk: the 95 % intervals of N and K hold the truth on 85 % or more (the
    benchmark's 200 hours per noise measure it at 93-97 %; a too-narrow interval, as with Greenhall's degrees of
    freedom for white noise at 4 samples or a flat term fitted under a bump, fails here)."""
    truth = RestNoise(density=0.01, random_walk=3e-4)
    n_in, k_in = [], []
    for seed in range(20):
        for a in noise(simulate_rest(100 + seed, 1800.0, FS, truth)).gyro:
            n_in.append(a.density.lo95 <= truth.density <= a.density.hi95)
            if a.random_walk.seen:
                k_in.append(a.random_walk.lo95 <= truth.random_walk <= a.random_walk.hi95)
    assert np.mean(n_in) >= 0.85 and len(k_in) >= 20 and np.mean(k_in) >= 0.85, (np.mean(n_in), len(k_in), np.mean(k_in))


def test_a_recording_that_moves_is_refused_with_when() -> None:
    rec = simulate_rest(1, 600.0, FS, RestNoise(density=0.01), RestNoise(density=1e-4))
    gyro = rec.gyro.copy()
    gyro[int(250 * FS):int(252 * FS), 2] += 45.0  # turned by hand for two seconds
    moved = type(rec)(rec.t, gyro, rec.accel, meta=rec.meta)
    with pytest.raises(Refusal, match=r"turns 250\.0 s into the recording") as exc:
        noise(moved)
    assert exc.value.code == "not_a_rest"


def test_samples_missing_from_the_time_stamps_are_counted_and_said() -> None:
    rec = simulate_rest(2, 600.0, FS, RestNoise(density=0.01))
    keep = np.ones(len(rec), bool)
    keep[[1000, 1001, 1002, 30_000]] = False  # three samples lost in a row, and one more
    report = noise(rec.select(keep))
    assert report.lost_samples == 4 and report.to_json()["lost_samples"] == 4
    assert "4 samples are missing from the recording" in report.text()
    assert noise(rec).lost_samples == 0


def test_a_short_rest_is_refused_with_how_long_it_must_be() -> None:
    with pytest.raises(Refusal, match="too short for an Allan analysis: it needs at least") as exc:
        noise(simulate_rest(1, 2.0, FS, RestNoise(density=0.01)))
    assert exc.value.code == "rest_too_short"


def test_gyrocal_noise_prints_the_table_writes_the_plot_and_kalibrs_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "rest.csv"
    write_native_csv(simulate_rest(5, 1200.0, FS, RestNoise(density=0.01, random_walk=3e-4), RestNoise(density=1e-4)), path)
    assert main(["noise", str(path), "--kalibr", str(tmp_path / "imu.yaml"), "--topic", "/wearable/imu"]) == 0
    out = capsys.readouterr().out
    assert "gyroscope" in out and "deg/sqrt(h)" in out and "accelerometer" in out
    png = tmp_path / "rest.allan.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    assert "rostopic: /wearable/imu" in (tmp_path / "imu.yaml").read_text()
    assert main(["noise", str(path), "--json", "--plot", str(tmp_path / "p.png")]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["units"]["gyro"]["noise_density"] == "(deg/s)/sqrt(Hz)"
    x = d["gyro"][0]
    assert x["noise_density"]["seen"] and len(x["noise_density"]["ci95"]) == 2
    assert len(x["curve"]["tau_s"]) == len(x["curve"]["adev"]) == len(x["curve"]["fit_adev"]) >= 4


def test_gyrocal_noise_refuses_a_turned_recording_with_exit_3(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from calib.simulator import simulate

    rec, _ = simulate(1)
    path = tmp_path / "paper.csv"
    write_native_csv(rec, path)
    assert main(["noise", str(path)]) == 3
    err = capsys.readouterr().err
    assert "gyrocal: error: the device turns" in err and "the noise is read from one rest" in err
