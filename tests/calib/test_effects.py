"""Tests of the effect catalogue (calib.effects) and the concealed-effect generator (calib.simulator.concealed).

Each effect is checked against its own model equation on noise-free recordings, then the CLI and
the generator's determinism, ranges and concealment.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib.effects import (
    CATALOGUE,
    EFFECTS,
    TEMP_RESOLUTION_C,
    AxisMisalignment,
    BiasDrift,
    BiasInstability,
    ClockError,
    GSensitivity,
    PlacementError,
    SampleLoss,
    Saturation,
    ScaleAsymmetry,
    ScaleNonlinearity,
    SimulationConfigError,
    effect_from_dict,
    parse_effect,
)
from calib.errors import GyrocalError
from calib.simulator import ProtocolScript, SensorParams, Still, Turn, extended_protocol_script, simulate
from calib.simulator.concealed import EFFECT_NAMES, PROTOCOLS, RANGES, draw_concealed, protocol_script

FS = 104.0
PARAMS = SensorParams([0.9, 1.1, 1.05], [2.0, -3.0, 0.5])


def sim(*effects, seed: int = 5, script: ProtocolScript | None = None, params: SensorParams = PARAMS):
    """Noise-free recording (gyro and accelerometer) with the given effects."""
    return simulate(seed, noise=0.0, params=params, script=script, effects=effects, accel_noise_g=0.0)


def calibrated(rec, params: SensorParams = PARAMS) -> np.ndarray:
    """g0 = K m + b, the rate the paper's model gives."""
    return rec.gyro * params.k + params.b


def closing_rotation(rate_dps: np.ndarray, dt: np.ndarray | float) -> Rotation:
    """Product of Exp(g_i dt_i) in time order."""
    incs = Rotation.from_rotvec(np.radians(rate_dps) * np.reshape(dt, (-1, 1)))
    pose = Rotation.identity()
    for inc in incs:
        pose = pose * inc
    return pose


def clean_turns(*turns: tuple[str, float, float]) -> ProtocolScript:
    """Rest, then turns (axis, angle, duration) about exact sensor axes without wobble, each followed by rest."""
    segs: list = [Still(2.0)]
    for axis, angle, duration in turns:
        segs += [Turn(axis, angle, duration, wobble_deg=0.0, tilt=0), Still(2.0)]
    return ProtocolScript(tuple(segs))


# --------------------------------------------------------------------------- models against their equations


def test_catalogue_is_complete_and_documented():
    assert CATALOGUE == (
        "bias_drift", "axis_misalignment", "g_sensitivity", "scale_asymmetry", "scale_nonlinearity",
        "saturation", "sample_loss", "placement_error", "clock_error", "bias_instability",
    )
    for name in CATALOGUE:
        cls = EFFECTS[name]
        assert cls.usage and cls.__doc__ and name in RANGES


def test_bias_drift_over_time():
    d = np.array([0.003, -0.002, 0.001])
    rec, truth = sim(BiasDrift(d))
    np.testing.assert_allclose(calibrated(rec) + np.outer(truth.t_true, d), truth.rate, atol=1e-10)
    assert rec.temp is None and set(truth.to_dict()["effects"][0]) == {"name", "rate_dps_per_s"}


def test_bias_drift_against_temperature_records_the_temperature():
    c = np.array([0.03, -0.01, 0.02])
    effect = BiasDrift(0.0, c, temp_rise_c=8.0, temp_tau_s=60.0, temp0_c=24.0)
    rec, truth = sim(effect)
    assert rec.temp is not None and rec.temp[0] == 24.0
    np.testing.assert_allclose(rec.temp / TEMP_RESOLUTION_C, np.round(rec.temp / TEMP_RESOLUTION_C))
    assert np.all(np.diff(rec.temp) >= 0) and rec.temp[-1] - rec.temp[0] > 2.0
    expected_t = 24.0 + 8.0 * (1 - np.exp(-truth.t_true / 60.0))
    np.testing.assert_allclose(rec.temp, expected_t, atol=TEMP_RESOLUTION_C / 2 + 1e-12)
    # b(T) = b + c (T - T0), with T the recorded (quantised) temperature
    resid = calibrated(rec) + np.outer(rec.temp - rec.temp[0], c) - truth.rate
    assert np.max(np.abs(resid)) <= np.max(np.abs(c)) * TEMP_RESOLUTION_C / 2 + 1e-9
    assert truth.to_dict()["effects"][0]["temp_rise_c"] == 8.0


def test_axis_misalignment_is_an_upper_triangular_K():
    effect = AxisMisalignment([0.01, 0.005, -0.008])
    rec, truth = sim(effect)
    K = effect.matrix(PARAMS.k)
    assert K[1, 0] == K[2, 0] == K[2, 1] == 0.0 and K[0, 1] == 0.01 and K[0, 2] == 0.005 and K[1, 2] == -0.008
    np.testing.assert_allclose(rec.gyro @ K.T + PARAMS.b, truth.rate, atol=1e-10)
    assert np.max(np.abs(calibrated(rec) - truth.rate)) > 1.0  # the diagonal model misses it in the turns


def test_g_sensitivity_adds_G_a_to_the_readings():
    G = np.array([[0.05, -0.1, 0.02], [0.03, 0.08, -0.06], [0.1, 0.0, 0.04]])
    rec, truth = sim(GSensitivity(G))
    np.testing.assert_allclose((rec.gyro - rec.accel @ G.T) * PARAMS.k + PARAMS.b, truth.rate, atol=1e-10)
    still = truth.stages[0]
    np.testing.assert_allclose(rec.gyro[still.start : still.end], np.tile(-PARAMS.b / PARAMS.k + G[:, 2], (still.n, 1)), atol=1e-10)
    np.testing.assert_array_equal(parse_effect("g_sensitivity", "0.1,0.2,0.3").matrix_dps_per_g, np.diag([0.1, 0.2, 0.3]))


def test_scale_asymmetry_scales_each_direction():
    s = np.array([0.01, -0.006, 0.004])
    script = clean_turns(("x", 360.0, 3.0), ("x", -360.0, 3.0), ("z", -360.0, 3.0))
    rec, truth = sim(ScaleAsymmetry(s), script=script)
    g0 = calibrated(rec)
    np.testing.assert_allclose((1 + s * np.sign(g0)) * g0, truth.rate, atol=1e-10)
    base, _ = sim(script=script)
    still = truth.stages[0]
    np.testing.assert_allclose(rec.gyro[still.start : still.end], base.gyro[still.start : still.end], atol=1e-12)
    turns = [st for st in truth.stages if st.kind == "turn"]
    swept = [np.sum(g0[st.start : st.end], axis=0) / FS for st in turns]
    assert swept[0][0] == pytest.approx(360.0 / (1 + s[0]), rel=1e-9)
    assert swept[1][0] == pytest.approx(-360.0 / (1 - s[0]), rel=1e-9)
    assert swept[2][2] == pytest.approx(-360.0 / (1 - s[2]), rel=1e-9)


def test_scale_nonlinearity_grows_with_the_rate():
    n = np.array([0.008, -0.004, 0.006])
    script = clean_turns(("x", 360.0, 8.0), ("x", 360.0, 1.5))
    rec, truth = sim(ScaleNonlinearity(n), script=script)
    g0 = calibrated(rec)
    np.testing.assert_allclose((1 + n * np.abs(g0) / 1000.0) * g0, truth.rate, atol=1e-10)
    slow, fast = (st for st in truth.stages if st.kind == "turn")
    deficit = [360.0 - np.sum(g0[st.start : st.end, 0]) / FS for st in (slow, fast)]
    assert 0 < deficit[0] < deficit[1]  # positive n: the fast turn reads short by more
    assert parse_effect("scale_nonlinearity", "0.005:500").ref_rate_dps == 500.0


def test_saturation_clips_at_full_scale_and_states_it():
    base, _ = sim()
    rec, truth = sim(Saturation(150.0))
    assert rec.meta.gyro_full_scale_dps == 150.0
    inside = np.abs(base.gyro) < 150.0
    np.testing.assert_array_equal(rec.gyro[inside], base.gyro[inside])
    assert np.any(~inside) and np.all(rec.gyro[~inside] == 150.0 * np.sign(base.gyro[~inside]))
    assert any("saturated" in st.flags for st in truth.stages if st.kind == "turn")


def test_sample_loss_leaves_gaps_in_counter_and_time():
    rec, truth = sim(SampleLoss(prob=0.01, burst=4))
    base, _ = sim()
    gaps = np.diff(rec.seq)
    assert np.any(gaps > 1) and np.all(gaps >= 1) and np.all(gaps[gaps > 1] >= 5)
    np.testing.assert_allclose(rec.t, rec.seq / FS)
    np.testing.assert_array_equal(rec.gyro, base.gyro[rec.seq])
    np.testing.assert_allclose(truth.t_true, rec.t)


def test_placement_error_breaks_closure_and_tilts_the_accelerometer():
    errors = np.array([[1.0, -0.5, 2.0], [0.0, 0.0, 1.5], [0.4, 0.3, -1.0]])
    rec, truth = sim(PlacementError(errors_deg=errors))
    base, base_truth = sim()
    traj = truth.trajectory
    turns = [st for st in truth.stages if st.kind == "turn"]
    for st, e in zip(turns, errors, strict=False):
        r_start = traj.attitude[st.start]
        closure = closing_rotation(truth.rate[st.start : st.end], 1.0 / FS)
        np.testing.assert_allclose(closure.as_rotvec(), r_start.inv().apply(np.radians(e)), atol=1e-10)
        # accelerometer at rest after the turn: gravity seen from the misplaced pose
        after = (Rotation.from_rotvec(np.radians(e)) * r_start).inv().apply([0.0, 0.0, 1.0])
        np.testing.assert_allclose(rec.accel[st.end + 5], after, atol=1e-10)
        tilt = np.degrees(np.arccos(np.clip(rec.accel[st.end + 5] @ rec.accel[st.start - 5], -1, 1)))
        assert tilt == pytest.approx(np.hypot(e[0], e[1]), abs=0.02)  # heading leaves gravity alone
    # pure heading (turn 2): the accelerometer sees nothing, the closure sees it all
    np.testing.assert_allclose(rec.accel[turns[1].end + 5], rec.accel[turns[1].start - 5], atol=1e-12)
    # outside the last quarter of each turn the body rates are the unperturbed ones
    ramp = np.zeros(len(rec), bool)
    for st in turns:
        ramp[st.end - round(0.25 * st.n) : st.end] = True
    np.testing.assert_allclose(truth.rate[~ramp], base_truth.rate[~ramp], atol=1e-9)
    with pytest.raises(GyrocalError, match="3 turns"):
        sim(PlacementError(errors_deg=errors[:2]))


def test_placement_error_draws_have_the_stated_spread():
    effect = PlacementError(1.5, heading_std_deg=3.0)
    e = effect.draw_errors(4000, np.random.default_rng(0))
    np.testing.assert_allclose(e.std(axis=0), [1.5, 1.5, 3.0], rtol=0.05)


def test_clock_error_stretches_device_time():
    e = 0.02
    script = clean_turns(("y", 360.0, 3.0))
    rec, truth = sim(ClockError(e), script=script)
    base, _ = sim(script=script)
    np.testing.assert_array_equal(rec.t, base.t)  # device stamps i / fs as before
    np.testing.assert_allclose(truth.t_true, rec.t / (1 + e))  # t_device = (1 + e) t_true
    st = truth.stages[1]
    g0 = calibrated(rec)[st.start : st.end]
    dt_dev = 1.0 / FS
    assert np.sum(g0[:, 1]) * dt_dev == pytest.approx(360.0 * (1 + e), rel=1e-9)  # over device time
    assert np.sum(g0[:, 1]) * dt_dev / (1 + e) == pytest.approx(360.0, rel=1e-9)  # over true time
    assert closing_rotation(truth.rate[st.start : st.end], dt_dev / (1 + e)).magnitude() < 1e-10


def test_bias_instability_is_gauss_markov():
    sigma, tau = 0.01, 2.0
    script = ProtocolScript((Still(600.0),))
    rec, truth = sim(BiasInstability(sigma, tau), script=script)
    x = truth.rate - calibrated(rec)  # g = K m + b + x
    phi = np.exp(-1.0 / (FS * tau))
    innovation = x[1:] - phi * x[:-1]
    np.testing.assert_allclose(innovation.std(axis=0), sigma * np.sqrt(1 - phi**2), rtol=0.03)
    # 300 correlation times per axis, three axes pooled: a few per cent precision
    assert np.sqrt(np.mean(x**2)) == pytest.approx(sigma, rel=0.2)
    phi_hat = np.sum(x[1:] * x[:-1]) / np.sum(x[:-1] ** 2)
    assert -1.0 / (FS * np.log(phi_hat)) == pytest.approx(tau, rel=0.2)


def test_effects_act_alone_and_deterministically():
    plain, _ = simulate(8)
    for effect in (BiasInstability(0.01, 10.0), PlacementError(1.0), SampleLoss(prob=0.01)):
        a, _ = simulate(8, effects=(effect,))
        b, _ = simulate(8, effects=(effect,))
        np.testing.assert_array_equal(a.gyro, b.gyro)  # the same seed draws the same effect
        if isinstance(effect, SampleLoss):
            # it only drops samples: those delivered are the plain recording's, at their sample numbers
            assert 0 < len(plain) - len(a) < 0.05 * len(plain)
            np.testing.assert_array_equal(a.gyro, plain.gyro[a.seq - plain.seq[0]])
            continue
        # it changes the readings, and nothing else: same times, same number of samples
        assert len(a) == len(plain) and not np.allclose(a.gyro, plain.gyro)
        np.testing.assert_array_equal(a.t, plain.t)


# --------------------------------------------------------------------------- CLI values


CLI_VALUES = {
    "bias_drift": "0.002,-0.001,0.0005",
    "axis_misalignment": "0.01,0.005,-0.008",
    "g_sensitivity": "0.05,0.1,-0.02,0,0.08,0,0.01,0,0.04",
    "scale_asymmetry": "0.005",
    "scale_nonlinearity": "0.004,0.006,-0.003:800",
    "saturation": "250,0.0076",
    "sample_loss": "0.01,6",
    "placement_error": "1.0,2.5",
    "clock_error": "0.015",
    "bias_instability": "0.01,20",
}


@pytest.mark.parametrize("name", CATALOGUE)
def test_parse_effect_round_trip(name):
    effect = parse_effect(name, CLI_VALUES[name])
    d = effect.to_dict()
    assert d["name"] == name
    json.dumps(d)
    assert effect_from_dict(d).to_dict() == d
    with pytest.raises(GyrocalError, match=name):
        parse_effect(name, "1,2,3,4,5,6,7,8,9,10" if name != "g_sensitivity" else "1,2")


def test_parse_effect_values_mean_what_the_help_says():
    drift = parse_effect("bias_drift", "0:0.03,0.01,-0.02:6:90")
    np.testing.assert_array_equal(drift.rate_dps_per_s, 0.0)
    np.testing.assert_array_equal(drift.temp_coeff_dps_per_c, [0.03, 0.01, -0.02])
    assert (drift.temp_rise_c, drift.temp_tau_s) == (6.0, 90.0)
    np.testing.assert_array_equal(parse_effect("axis_misalignment", "0.01,0.005,-0.008").off_diagonal, [0.01, 0.005, -0.008])
    np.testing.assert_array_equal(parse_effect("scale_asymmetry", "0.005").asymmetry, [0.005] * 3)
    place = parse_effect("placement_error", "1.0,2.5")
    np.testing.assert_array_equal(place.stds_deg, [1.0, 1.0, 2.5])
    assert parse_effect("clock_error", "1e-4").error == 1e-4
    bi = parse_effect("bias_instability", "0.01")
    assert (bi.sigma_dps, bi.tau_s) == (0.01, 30.0)
    for name, value, fragment in (
        ("clock_error", "0.7", "between -0.5 and 0.5"),
        ("bias_instability", "-0.01", "non-negative"),
        ("axis_misalignment", "0.01,0.02", "KXY,KXZ,KYZ"),
        ("bias_drift", "0.01:0.02", "RISE"),
    ):
        with pytest.raises(SimulationConfigError, match=fragment):
            parse_effect(name, value)


def _gyrocal(*args: str, cwd: Path) -> subprocess.Popen[str]:
    exe = Path(sys.executable).with_name("gyrocal")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "calib.cli.main"]
    return subprocess.Popen([*cmd, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=cwd)


def test_cli_simulates_every_effect(tmp_path):
    from calib.io.readers import read_recording

    runs = {
        name: _gyrocal("simulate", "--seed", "3", "--effect", f"{name}={CLI_VALUES[name]}", "-o", f"{name}.csv", "--truth", cwd=tmp_path)
        for name in CATALOGUE
    }
    temp = _gyrocal("simulate", "--seed", "3", "--effect", "bias_drift=0:0.03:6", "-o", "t.csv", cwd=tmp_path)
    bad = _gyrocal("simulate", "--seed", "3", "--effect", "clock_error=fast", "-o", "x.csv", cwd=tmp_path)
    for name, proc in runs.items():
        stdout, stderr = proc.communicate(timeout=120)
        assert proc.returncode == 0, stderr
        truth = json.loads(stdout)
        assert [e["name"] for e in truth["effects"]] == [name]
        assert truth["effects"][0] == parse_effect(name, CLI_VALUES[name]).to_dict()
        assert len(read_recording(tmp_path / f"{name}.csv")) > 1000
    _, stderr = temp.communicate(timeout=120)
    assert temp.returncode == 0, stderr
    assert read_recording(tmp_path / "t.csv").temp is not None
    _, stderr = bad.communicate(timeout=120)
    assert bad.returncode != 0 and "clock_error" in stderr and "Traceback" not in stderr


def test_cli_simulates_the_extended_protocol_that_reveals_a_nonlinearity(tmp_path):
    """The same scale nonlinearity, simulated with one turn per axis and with the extended protocol: the diagnosis
    says the first cannot show it and names it in the second, with the --effect value that reproduces it."""
    from calib.io.readers import read_recording
    from calib.stages.detector import detect_stages

    effect = "scale_nonlinearity=0.01"
    sims = {p: _gyrocal("simulate", "--seed", "5", "--protocol", p, "--effect", effect, "-o", f"{p}.csv", cwd=tmp_path)
            for p in ("paper", "extended")}
    for proc in sims.values():
        _, stderr = proc.communicate(timeout=120)
        assert proc.returncode == 0, stderr
    turns = [s for s in detect_stages(read_recording(tmp_path / "extended.csv")) if s.kind == "turn"]
    assert [s.axis for s in turns] == [a for a in "xyz" for _ in range(4)]
    diags = {p: _gyrocal("diagnose", f"{p}.csv", "--json", cwd=tmp_path) for p in sims}
    out = {}
    for p, proc in diags.items():
        stdout, stderr = proc.communicate(timeout=300)
        assert proc.returncode == 0, stderr
        out[p] = json.loads(stdout)
    assert out["paper"]["effects"] == []
    assert "scale_nonlinearity" in [n["name"] for n in out["paper"]["not_identifiable"]]
    (named,) = out["extended"]["effects"]
    assert named["name"] == "scale_nonlinearity"
    assert named["evidence"]["simulate"].startswith("scale_nonlinearity=")
    assert named["fit"]["after"] < 0.05 * named["fit"]["before"]
    bad = _gyrocal("simulate", "--seed", "4", "--protocol", "figure-eight", "-o", "x.csv", cwd=tmp_path)
    _, stderr = bad.communicate(timeout=60)
    assert bad.returncode != 0 and "extended" in stderr and "Traceback" not in stderr


# --------------------------------------------------------------------------- concealed generator


def test_concealed_is_deterministic_by_seed():
    a = draw_concealed(12, "random", protocol="paper")
    b = draw_concealed(12, "random", protocol="paper")
    c = draw_concealed(13, "random", protocol="paper")
    assert a.effect_name == b.effect_name and a.magnitude == b.magnitude
    np.testing.assert_array_equal(a.recording.gyro, b.recording.gyro)
    np.testing.assert_array_equal(a.host_t, b.host_t)
    assert a.to_dict() == b.to_dict()
    assert not np.array_equal(a.recording.gyro[:100], c.recording.gyro[:100])


def test_concealed_magnitudes_stay_in_their_ranges():
    names = set()
    for seed in range(40):
        case = draw_concealed(seed, "random")
        names.add(case.effect_name)
        r = RANGES[case.effect_name]
        assert r.low <= case.magnitude <= r.high, (case.effect_name, case.magnitude)
        assert 0.02 <= case.noise_dps <= 0.1
        fx = case.truth.to_dict()["effects"]
        assert [e["name"] for e in fx] == [case.effect_name]
    assert len(names) >= 8  # the draw reaches (nearly) the whole catalogue


@pytest.mark.parametrize("name", EFFECT_NAMES)
def test_concealed_case_hides_the_effect(name):
    null = draw_concealed(4, None, with_temp=True)
    case = draw_concealed(4, name, with_temp=True)
    assert null.effect_name is None and null.magnitude == 0.0 and null.effect is None
    assert [e["name"] for e in null.truth.to_dict()["effects"]] == ["temperature"]
    # the recording carries the same kind of data and metadata, whatever was drawn
    for rec in (null.recording, case.recording):
        assert rec.accel is not None and rec.seq is not None and rec.temp is not None
        assert rec.meta.device_id == null.recording.meta.device_id and rec.meta.source == null.recording.meta.source
        assert rec.meta.gyro_full_scale_dps is not None
    np.testing.assert_array_equal(case.truth.k, null.truth.k)
    if name == "saturation":
        assert case.recording.meta.gyro_full_scale_dps == case.magnitude < np.max(np.abs(null.recording.gyro))
    if name == "bias_drift":  # with a temperature channel the drift follows the temperature
        assert case.effect.has_temperature
        assert case.truth.effects[0]["name"] == "bias_drift"
    if name not in ("sample_loss", "clock_error", "placement_error", "bias_instability"):
        np.testing.assert_array_equal(case.recording.t, null.recording.t)


def test_concealed_without_accelerometer_counter_and_with_extended_protocol():
    case = draw_concealed(6, "sample_loss", protocol="extended", with_accel=False, with_seq=False, noise=0.05)
    rec = case.recording
    assert rec.accel is None and rec.seq is None and case.noise_dps == 0.05
    assert np.max(np.diff(rec.t)) > 1.5 / FS  # the loss still shows in the time stamps
    turns = [st for st in case.truth.stages if st.kind == "turn"]
    assert len(turns) == 12
    assert [st.axis for st in turns] == [a for a in "xyz" for _ in range(4)]
    assert [np.sign(st.angle_deg) for st in turns[:4]] == [1, -1, 1, -1]
    slow = [st.end_s - st.start_s for st in turns[:2]]
    fast = [st.end_s - st.start_s for st in turns[2:4]]
    assert min(slow) >= 6.0 - 0.02 and max(fast) <= 1.8 + 0.02
    assert len(case.host_t) == len(rec)


def test_concealed_clock_error_shows_against_host_time():
    case = draw_concealed(9, "clock_error")
    e = case.effect.error
    assert abs(e) == case.magnitude
    rec = case.recording
    # device time runs (1 + e) times host time; the link delay is a constant plus a few ms of jitter
    slope = np.polyfit(case.host_t, rec.t, 1)[0]
    assert slope == pytest.approx(1 + e, abs=2e-4)
    null = draw_concealed(9, None)
    assert np.polyfit(null.host_t, null.recording.t, 1)[0] == pytest.approx(1.0, abs=2e-4)


def test_concealed_rejects_bad_requests():
    with pytest.raises(GyrocalError, match="effect must be"):
        draw_concealed(1, "wind")
    with pytest.raises(GyrocalError, match="protocol"):
        draw_concealed(1, None, protocol="ferraris")
    with pytest.raises(GyrocalError, match="seed"):
        draw_concealed(-1)
    assert protocol_script("extended", np.random.default_rng(0)).turns[0].duration_s >= 6.0
    assert len(extended_protocol_script().turns) == 12 and set(PROTOCOLS) == {"paper", "extended"}
