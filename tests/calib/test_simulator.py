"""Tests of the protocol simulator (calib.simulator) and its effect pipeline (calib.effects)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib.effects import BiasDrift, Effect, SampleLoss, Saturation, SimulationConfigError, parse_effect
from calib.errors import GyrocalError
from calib.recording import Recording
from calib.simulator import (
    Motion,
    ProtocolScript,
    SensorParams,
    Still,
    Truth,
    Turn,
    paper_protocol_script,
    simulate,
    simulate_batch,
)


def integrate(rate_dps: np.ndarray, fs: float) -> Rotation:
    """Product of Exp(g_i dt) over the samples, in time order (body-frame increments)."""
    pose = Rotation.identity()
    for inc in Rotation.from_rotvec(np.radians(rate_dps) / fs):
        pose = pose * inc
    return pose


@pytest.fixture(scope="module")
def paper_run() -> tuple[Recording, Truth]:
    return simulate(7, noise=0.03)


def test_paper_run_shape_and_stages(paper_run):
    rec, truth = paper_run
    kinds = [s.kind for s in truth.stages]
    assert kinds == ["still", "turn", "still", "turn", "still", "turn", "still"]
    assert [s.axis for s in truth.stages if s.kind == "turn"] == ["x", "y", "z"]
    assert rec.gyro.shape == (len(rec), 3) and rec.accel.shape == (len(rec), 3)
    np.testing.assert_array_equal(rec.seq, np.arange(len(rec)))
    np.testing.assert_allclose(rec.t, np.arange(len(rec)) / 104.0)
    assert rec.fs == 104.0
    for s in truth.stages:
        if s.kind == "still":
            assert s.n == round(3.0 * 104)
        else:
            assert 2.5 * 104 - 1 <= s.n <= 5.0 * 104 + 1
    assert truth.stages[-1].end == len(rec)
    # contiguous segments
    for a, b in zip(truth.stages, truth.stages[1:], strict=False):
        assert a.end == b.start and a.end_s == pytest.approx(b.start_s)


def test_turns_close_exactly_and_sweep_360(paper_run):
    rec, truth = paper_run
    for st, axis in zip(truth.stages, truth.segment_axes, strict=False):
        if st.kind != "turn":
            continue
        pose = integrate(truth.rate[st.start : st.end], truth.fs)
        assert pose.magnitude() < 1e-12
        swept = np.sum(truth.rate[st.start : st.end] @ axis) / truth.fs
        assert swept == pytest.approx(360.0, abs=1.0)  # wobble shares a little of the motion


@pytest.mark.parametrize("fs", [52.0, 416.0])
def test_turns_close_at_other_rates(fs):
    rec, truth = simulate(4, fs=fs)
    assert rec.fs == fs and truth.stages[0].n == round(3.0 * fs)
    for st in truth.stages:
        if st.kind == "turn":
            assert integrate(truth.rate[st.start : st.end], fs).magnitude() < 1e-12


def test_turn_without_wobble_sweeps_exactly_its_angle():
    script = ProtocolScript((Still(1.0), Turn("y", -360.0, duration_s=3.0, wobble_deg=0.0, tilt=(0.05, -0.08)), Still(1.0)))
    rec, truth = simulate(3, noise=0.0, script=script)
    st = truth.stages[1]
    axis = truth.turn_axes[1]
    np.testing.assert_allclose(np.sum(truth.rate[st.start : st.end], axis=0) / truth.fs, -360.0 * axis, atol=1e-9)
    np.testing.assert_allclose(axis, np.array([0.05, 1.0, -0.08]) / np.linalg.norm([0.05, 1.0, -0.08]))
    assert integrate(truth.rate[st.start : st.end], truth.fs).magnitude() < 1e-12


def test_trajectory_rates_are_pose_increments(paper_run):
    _, truth = paper_run
    traj = truth.trajectory
    inc = traj.attitude[:-1].inv() * traj.attitude[1:]
    np.testing.assert_allclose(np.radians(traj.rate) / traj.fs, inc.as_rotvec(), atol=1e-12)
    assert (traj.attitude[0].inv() * traj.attitude[-1]).magnitude() < 1e-12  # ends in the start pose


def test_deterministic_by_seed():
    a_rec, a_truth = simulate(11, noise=0.15)
    b_rec, b_truth = simulate(11, noise=0.15)
    c_rec, _ = simulate(12, noise=0.15)
    np.testing.assert_array_equal(a_rec.gyro, b_rec.gyro)
    np.testing.assert_array_equal(a_rec.accel, b_rec.accel)
    assert a_truth.to_dict() == b_truth.to_dict()
    assert len(a_rec) != len(c_rec) or not np.array_equal(a_rec.gyro, c_rec.gyro)


def test_noise_free_readings_follow_eq1(paper_run):
    _, truth = paper_run
    params = SensorParams([0.9, 1.1, 1.05], [2.0, -3.0, 0.5])
    rec, tr = simulate(7, noise=0.0, params=params)
    np.testing.assert_array_equal(tr.k, params.k)
    np.testing.assert_allclose(rec.gyro * tr.k + tr.b, tr.rate, atol=1e-10)  # g = K m + b
    still = tr.stages[0]
    np.testing.assert_allclose(rec.gyro[still.start : still.end], np.tile(-params.b / params.k, (still.n, 1)), atol=1e-12)
    # same seed: same motion whatever the parameters
    np.testing.assert_allclose(tr.rate, truth.rate, atol=1e-12)


def test_noise_level(paper_run):
    rec, truth = paper_run
    still = truth.stages[0]
    m = rec.gyro[still.start : still.end]
    assert np.std(m, axis=0) == pytest.approx(np.full(3, 0.03), rel=0.25)
    np.testing.assert_allclose(-truth.k * m.mean(axis=0), truth.b, atol=0.03 * 1.2 * 5 / np.sqrt(still.n))


def test_stills_are_still_and_turns_move(paper_run):
    rec, truth = paper_run
    for st in truth.stages:
        rate = truth.rate[st.start : st.end]
        if st.kind == "still":
            assert np.all(rate == 0.0)
            np.testing.assert_allclose(np.linalg.norm(rec.accel[st.start : st.end].mean(axis=0)), 1.0, atol=2e-3)
        else:
            peak = np.max(np.abs(rate), axis=0)
            assert peak[["x", "y", "z"].index(st.axis)] > 60.0
            # zero rate at both ends of a turn: the first and last samples are slow
            assert np.linalg.norm(rate[0]) < 0.05 * peak.max() and np.linalg.norm(rate[-1]) < 0.05 * peak.max()


def test_accel_is_gravity_in_body_frame(paper_run):
    rec, truth = paper_run
    traj = truth.trajectory
    np.testing.assert_allclose(np.linalg.norm(traj.accel, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(traj.accel, traj.attitude[:-1].inv().apply([0.0, 0.0, 1.0]), atol=1e-12)
    np.testing.assert_allclose(rec.accel[:10], np.tile([0.0, 0.0, 1.0], (10, 1)), atol=0.01)
    assert np.std(rec.accel[:300] - traj.accel[:300]) == pytest.approx(0.002, rel=0.2)
    # halfway through the x turn the device is upside down-ish: z reads well below +1 g
    st = truth.stages[1]
    assert traj.accel[st.start : st.end, 2].min() < -0.9


def test_turn_stopping_short_does_not_close():
    script = ProtocolScript((Still(2.0), Turn("z", 300.0, duration_s=3.0, wobble_deg=0.0, tilt=0), Still(2.0)))
    rec, truth = simulate(5, noise=0.0, script=script)
    st = truth.stages[1]
    assert st.angle_deg == 300.0
    pose = integrate(truth.rate[st.start : st.end], truth.fs)
    assert np.degrees(pose.magnitude()) == pytest.approx(60.0, abs=1e-9)
    np.testing.assert_allclose(np.degrees(pose.as_rotvec()), [0.0, 0.0, -60.0], atol=1e-9)


def test_motion_changes_the_pose():
    script = ProtocolScript((Still(1.0), Motion([90.0, 0.0, 0.0], 1.0), Still(1.0), Turn("z", duration_s=3.0), Still(1.0)))
    rec, truth = simulate(2, noise=0.0, script=script)
    assert [s.kind for s in truth.stages] == ["still", "motion", "still", "turn", "still"]
    motion = truth.stages[1]
    pose = integrate(truth.rate[motion.start : motion.end], truth.fs)
    np.testing.assert_allclose(np.degrees(pose.as_rotvec()), [90.0, 0.0, 0.0], atol=1e-9)
    # after rolling +90 deg about x the up direction is body +y, and it stays there through the z turn
    after = truth.stages[2]
    np.testing.assert_allclose(truth.trajectory.accel[after.start], [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(truth.trajectory.accel[-1], [0.0, 1.0, 0.0], atol=1e-9)


def test_fast_turn_is_clipped_at_full_scale():
    script = ProtocolScript((Still(1.0), Turn("x", duration_s=0.6), Still(1.0)))
    rec, truth = simulate(4, noise=0.03, script=script, full_scale_dps=500.0)
    st = truth.stages[1]
    assert np.max(np.abs(truth.rate[st.start : st.end, 0])) > 700.0
    assert np.max(np.abs(rec.gyro)) == 500.0
    assert "saturated" in st.flags and "saturated" not in truth.stages[0].flags
    assert rec.meta.gyro_full_scale_dps == 500.0
    assert truth.to_dict()["effects"] == [{"name": "saturation", "full_scale_dps": 500.0, "resolution_dps": None}]


def test_quantisation():
    rec, _ = simulate(4, full_scale_dps=2000.0, resolution_dps=0.07)
    np.testing.assert_allclose(rec.gyro / 0.07, np.round(rec.gyro / 0.07), atol=1e-9)


def test_bias_drift_and_sample_loss_in_truth():
    effects = (BiasDrift([0.01, -0.02, 0.0]), SampleLoss(ranges=[(400, 420)], prob=0.002))
    base_rec, base = simulate(9, noise=0.0)
    rec, truth = simulate(9, noise=0.0, effects=effects)
    fx = truth.to_dict()["effects"]
    assert fx[0] == {"name": "bias_drift", "rate_dps_per_s": [0.01, -0.02, 0.0]}
    assert fx[1]["name"] == "sample_loss" and fx[1]["ranges"] == [[400, 420]] and fx[1]["prob"] == 0.002
    json.dumps(truth.to_dict())
    # lost samples: the counter shows the gaps and the times stay on the device clock
    assert len(rec) < len(base_rec) - 20
    assert not np.isin(np.arange(400, 420), rec.seq).any()
    np.testing.assert_allclose(rec.t, rec.seq / 104.0)
    np.testing.assert_array_equal(truth.rate, base.rate[rec.seq])
    # the x turn (312 .. ) contains the lost range: flagged, and re-indexed to the delivered rows
    turn_x = truth.stages[1]
    assert "counter_gap" in turn_x.flags
    assert rec.seq[turn_x.start] >= base.stages[1].start and rec.seq[turn_x.end - 1] < base.stages[1].end
    # drift: m = (g - b - d t) / k
    expect = (base.rate[rec.seq] - truth.b - np.outer(rec.t, [0.01, -0.02, 0.0])) / truth.k
    np.testing.assert_allclose(rec.gyro, expect, atol=1e-10)


def test_effects_do_not_change_the_other_draws():
    rec_a, _ = simulate(21, noise=0.1)
    rec_b, _ = simulate(21, noise=0.1, effects=(BiasDrift([0.0, 0.0, 0.0]),))
    np.testing.assert_array_equal(rec_a.gyro, rec_b.gyro)


def test_custom_effect_hooks_run_in_order():
    class Shift(Effect):
        name = "shift"

        def on_sensor(self, m, ctx, rng):
            return m + 1.0

    rec_a, _ = simulate(1, noise=0.0)
    rec_b, truth = simulate(1, noise=0.0, effects=(Shift(),))
    np.testing.assert_allclose(rec_b.gyro - rec_a.gyro, 1.0)
    assert truth.to_dict()["effects"] == [{"name": "shift"}]


def test_parse_effect_from_cli_values():
    drift = parse_effect("bias_drift", "0.01,0,-0.02")
    np.testing.assert_array_equal(drift.rate_dps_per_s, [0.01, 0.0, -0.02])
    np.testing.assert_array_equal(parse_effect("bias-drift", "0.5").rate_dps_per_s, [0.5, 0.5, 0.5])
    loss = parse_effect("sample_loss", "0.02,4")
    assert (loss.prob, loss.burst) == (0.02, 4)
    sat = parse_effect("saturation", "500,0.07")
    assert (sat.full_scale_dps, sat.resolution_dps) == (500.0, 0.07)
    with pytest.raises(GyrocalError, match="known effects: bias_drift"):
        parse_effect("wind", "3")
    with pytest.raises(GyrocalError, match="FULL_SCALE"):
        parse_effect("saturation", "fast")
    with pytest.raises(GyrocalError, match="RX,RY,RZ"):
        parse_effect("bias_drift", "1,2")


def test_sample_loss_bursts():
    loss = SampleLoss(prob=0.01, burst=5)
    lost = loss.lost_mask(np.arange(20000), np.random.default_rng(0))
    assert lost.mean() == pytest.approx(1 - 0.99**5, rel=0.15)
    runs = np.diff(np.flatnonzero(np.diff(np.concatenate([[0], lost.astype(int), [0]]))))[::2]
    assert runs.min() >= 5


def test_bad_inputs_raise_clear_errors():
    with pytest.raises(GyrocalError, match="Turn.axis"):
        Turn("w")
    with pytest.raises(GyrocalError, match="seed"):
        simulate(-1)
    with pytest.raises(GyrocalError, match="Effect"):
        simulate(1, effects=("drift",))
    with pytest.raises(GyrocalError, match="too fast"):
        simulate(1, script=ProtocolScript((Still(1.0), Turn("x", 720.0, duration_s=0.03))))
    with pytest.raises(SimulationConfigError, match="prob"):
        SampleLoss(prob=1.5)
    with pytest.raises(GyrocalError, match="full_scale_dps"):
        Saturation(-3.0)


def test_paper_script_with_rng_is_fixed_and_reproducible():
    script = paper_protocol_script(np.random.default_rng(3), angle_deg=(-360.0, 360.0, -360.0))
    r1, t1 = simulate(1, noise=0.0, script=script)
    r2, t2 = simulate(2, noise=0.0, script=script, params=t1.params)
    np.testing.assert_array_equal(r1.gyro, r2.gyro)  # nothing left to draw but noise and parameters
    assert [s.angle_deg for s in t1.stages if s.kind == "turn"] == [-360.0, 360.0, -360.0]


def test_batch_layout_and_closure():
    batch = simulate_batch(5, 40, noise=0.03)
    R, n = batch.n_runs, batch.t.size
    assert batch.gyro.shape == (R, n, 3) == batch.rate.shape
    np.testing.assert_allclose(batch.t, np.arange(n) * batch.dt)
    assert np.all(batch.still0 == [0, 312])
    assert np.all(batch.turns[:, 0, 0] == 312)
    assert np.all(batch.stills[:, 1, 0] == batch.turns[:, 0, 1]) and np.all(batch.stills[:, 3, 1] == n)
    assert np.all(batch.stills[:, 1:3, 1] - batch.stills[:, 1:3, 0] == 312)
    assert np.all((batch.k_true >= 0.8) & (batch.k_true <= 1.2)) and np.all(np.abs(batch.b_true) <= 5)
    for r in (0, 17, 39):
        for i in range(3):
            a, b = batch.turns[r, i]
            assert integrate(batch.rate[r, a:b], batch.fs).magnitude() < 1e-12
            assert np.sum(batch.rate[r, a:b] @ batch.turn_axes[r, i]) / batch.fs == pytest.approx(360.0, abs=1.0)
        moving = np.zeros(n, bool)
        for a, b in batch.turns[r]:
            moving[a:b] = True
        assert np.all(batch.rate[r, ~moving] == 0.0)
    # every run differs in its motion
    assert len({tuple(x) for x in batch.turns[:, :, 1]}) > 30


def test_batch_equals_simulate_construction():
    batch = simulate_batch(8, 6, noise=0.0, params=([1.1, 0.9, 1.0], [1.0, 2.0, -3.0]))
    for r in (0, 5):
        rec, truth = simulate(99, noise=0.0, params=batch.params(r), script=batch.script(r))
        n = len(rec)
        assert n <= batch.t.size
        np.testing.assert_allclose(truth.rate, batch.rate[r, :n], atol=1e-9)
        np.testing.assert_allclose(rec.gyro, batch.gyro[r, :n], atol=1e-9)
        for i, st in enumerate(s for s in truth.stages if s.kind == "turn"):
            assert (st.start, st.end) == tuple(batch.turns[r, i])
            np.testing.assert_allclose(truth.turn_axes[i], batch.turn_axes[r, i], atol=1e-15)


def test_batch_noise_and_params():
    k = np.tile([1.1, 0.9, 1.0], (200, 1))
    batch = simulate_batch(1, 200, noise=0.15, params=(k, np.zeros(3)))
    np.testing.assert_array_equal(batch.k_true, k)
    still = batch.gyro[:, 0:312]
    assert np.std(still) == pytest.approx(0.15, rel=0.02)
    assert abs(np.mean(still)) < 0.003
    a = simulate_batch(1, 200, noise=0.15, params=(k, np.zeros(3)))
    np.testing.assert_array_equal(a.gyro, batch.gyro)
    # default paper draws: uniform k and b over their ranges
    wide = simulate_batch(2, 400, noise=0.03)
    assert np.mean(wide.k_true) == pytest.approx(1.0, abs=0.02)
    assert np.std(wide.b_true) == pytest.approx(10 / np.sqrt(12), rel=0.1)
