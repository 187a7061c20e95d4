"""The paper's Algorithm 1 (calib.estimators.paper) and its simulation study (calib.studies.paper_sim)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib import GyrocalError, ProtocolError, RecordingError, Stage
from calib.apply.correction import Correction
from calib.estimators import registry
from calib.estimators.paper import algorithm1, calibrate_paper
from calib.estimators.paper_batch import algorithm1_batch, rotvec_to_quat
from calib.estimators.registry import register_batch_method
from calib.numerics.quaternion import prefix_products
from calib.recording import Recording, RecordingMeta
from calib.simulator import Motion, ProtocolScript, SensorParams, Still, Turn, simulate, simulate_batch
from calib.stages.detector import detect_stages
from calib.stages.protocol import ProtocolStages
from calib.studies.paper_sim import paper_sim

FS = 104.0


def protocol(wobble_deg=None, extra_after_y=None):
    """The paper protocol; wobble_deg=0 gives turns about fixed axes; extra_after_y adds a segment."""
    segs = [Still(3.0)]
    for axis in "xyz":
        segs.append(Turn(axis, 360.0, wobble_deg=wobble_deg))
        if axis == "y" and extra_after_y is not None:
            segs.append(extra_after_y)
        segs.append(Still(3.0))
    return ProtocolScript(tuple(segs))


def protocol_stages(stages, y_end_stage=None):
    """Still0 and the three turns from the simulator's true stages."""
    turns = {s.axis: s for s in stages if s.kind == "turn"}
    if y_end_stage is not None:  # let the y turn's stage run to the end of another stage
        y = turns["y"]
        turns["y"] = type(y)("turn", y.start, y_end_stage.end, y.start_s, y_end_stage.end_s, "y", y.angle_deg)
    return ProtocolStages(still0=stages[0], turns=turns, stills=[s for s in stages if s.kind == "still"])


def with_turns(stages, bounds):
    """The same protocol stages with other sample bounds for the x, y, z turns."""
    turns = {a: type(st)("turn", s, e, 0.0, 0.0, a) for (a, st), (s, e) in zip(stages.turns.items(), bounds, strict=False)}
    return ProtocolStages(still0=stages.still0, turns=turns, stills=stages.stills)


# --------------------------------------------------------------------------------------------- Algorithm 1


def test_rodrigues_prefix_product_matches_scipy_composition():
    rng = np.random.default_rng(3)
    phi = rng.normal(0.0, 0.05, (57, 4, 3))  # (samples, sequences, 3) rad
    P = prefix_products(rotvec_to_quat(phi.transpose(2, 0, 1)))  # (4, samples, sequences)
    for s in range(4):
        expected = Rotation.identity()
        for i in range(phi.shape[0]):
            expected = expected * Rotation.from_rotvec(phi[i, s])
            assert (Rotation.from_quat(P[:, i, s]).inv() * expected).magnitude() < 1e-12


def test_noise_free_recording_gives_the_parameters_and_the_bias_of_eq1():
    params = SensorParams(np.array([0.85, 1.12, 0.93]), np.array([3.1, -4.2, 1.7]))
    rec, truth = simulate(21, noise=0.0, params=params, script=protocol(wobble_deg=0.0))
    res = calibrate_paper(rec, stages=protocol_stages(truth.stages))
    assert res.method == "paper"
    np.testing.assert_allclose(res.k, params.k, atol=1e-9)
    np.testing.assert_allclose(res.b, params.b, atol=1e-9)
    # eq. 1: at rest g = k m + b = 0, so b = -k * mean(m) (not the -mean(m) of eq. 2 read literally)
    still = rec.gyro[truth.stages[0].start : truth.stages[0].end]
    np.testing.assert_allclose(Correction.from_result(res).apply(still)[0], 0.0, atol=1e-9)
    assert np.all(np.abs(res.b - (-still.mean(axis=0))) > 0.1)


@pytest.mark.parametrize("noise, k_tol, b_tol", [(0.03, 5.5e-3, 5.5e-3), (0.15, 2.5e-2, 2.5e-2)])
def test_recovers_parameters_within_the_papers_reported_accuracy(noise, k_tol, b_tol):
    batch = simulate_batch(5, 200, noise)
    k, b, iters = algorithm1_batch(batch.gyro, batch.dt, batch.still0, batch.turns)
    dk, db = k - batch.k_true, b - batch.b_true
    assert np.all(np.abs(dk) < k_tol / 5)
    assert np.mean(np.abs(db) < b_tol) > 0.97
    # unbiased: the median error is small next to the spread
    assert np.all(np.abs(np.median(db, axis=0)) < 0.2 * np.percentile(np.abs(db), 75, axis=0))
    assert np.all(np.abs(np.median(dk, axis=0)) < 2e-4)
    assert np.all((iters >= 2) & (iters <= 10))


def test_batch_equals_the_single_recording_path():
    batch = simulate_batch(8, 5, 0.15)
    k, b, iters = algorithm1_batch(batch.gyro, batch.dt, batch.still0, batch.turns)
    assert len({tuple(tb.ravel()) for tb in batch.turns}) == 5  # every run has its own bounds
    for r in range(5):
        rec = Recording(batch.t, batch.gyro[r], meta=RecordingMeta(sample_rate_hz=FS))
        still0 = Stage("still", int(batch.still0[r, 0]), int(batch.still0[r, 1]), 0.0, 0.0)
        turns = {a: Stage("turn", int(s), int(e), 0.0, 0.0, a) for a, (s, e) in zip("xyz", batch.turns[r], strict=False)}
        stages = ProtocolStages(still0=still0, turns=turns, stills=[])
        res = calibrate_paper(rec, stages=stages)
        np.testing.assert_allclose(res.k, k[r], atol=1e-10)
        np.testing.assert_allclose(res.b, b[r], atol=1e-9)
        assert res.iterations == iters[r]


@pytest.mark.parametrize("seed", [0, 1])
def test_calibrates_a_recording_with_detected_stages(seed):
    rec, truth = simulate(seed, noise=0.03)
    res = calibrate_paper(rec)
    assert np.all(np.abs(res.k - truth.k) < 1e-3)
    assert np.all(np.abs(res.b - truth.b) < 1e-2)
    assert [s.axis for s in res.stages if s.kind == "turn"] == ["x", "y", "z"]
    assert res.quality["turn_samples"]["x"] > 0 and res.warnings == []
    again = calibrate_paper(rec, stages=detect_stages(rec))
    np.testing.assert_array_equal(again.k, res.k)


def test_iterations_are_reported_and_the_iteration_matters():
    rec, truth = simulate(9, noise=0.03, script=protocol(wobble_deg=5.0))
    res = calibrate_paper(rec, stages=protocol_stages(truth.stages))
    hist = np.array(res.quality["k_history"])
    assert res.iterations == res.quality["iterations"] == len(hist) - 1 >= 2
    assert res.quality["converged"] is True
    np.testing.assert_allclose(hist[0], 1.0)
    assert np.linalg.norm(hist[-1] - hist[-2]) <= 1e-5
    # the first solve uses attitudes built from uncalibrated rates; re-solving moves k by more than tol
    assert np.linalg.norm(hist[2] - hist[1]) > 1e-5
    assert res.to_dict()["iterations"] == res.iterations
    for axis in "xyz":
        r = res.residuals[axis]
        assert r["angle_deg"] == pytest.approx(360.0, abs=1e-3)
        assert abs(abs(r["axis_angle_deg"]) - 360.0) < 40.0
        assert r["closure_deg"] < 1.0
    assert res.warnings == []

    # stopping after one solve is reported as not converged
    still0 = (truth.stages[0].start, truth.stages[0].end)
    turns = [(s.start, s.end) for s in truth.stages if s.kind == "turn"]
    _, _, iters = algorithm1_batch(rec.gyro[None], 1.0 / FS, np.array([still0]), np.array([turns]), max_iter=1)
    assert iters[0] == 2
    assert algorithm1(rec.t, rec.gyro, still0, turns, max_iter=1).converged is False


def test_turn_window_can_include_pause_samples_but_not_lose_moving_ones():
    rec, truth = simulate(12, noise=0.03, script=protocol())
    stages = protocol_stages(truth.stages)
    bounds = [(st.start, st.end) for st in stages.turns.values()]
    base = calibrate_paper(rec, stages=stages)
    widened = calibrate_paper(rec, stages=with_turns(stages, [(s - 52, e + 52) for s, e in bounds]))
    np.testing.assert_allclose(widened.k, base.k, atol=1e-4)
    s, e = bounds[1]
    short = [bounds[0], (s, s + int(0.9 * (e - s))), bounds[2]]  # the y turn's stage misses its last tenth
    cut = calibrate_paper(rec, stages=with_turns(stages, short))
    assert cut.k[1] - base.k[1] > 1e-3
    # the turn's off-axis tilt couples the equations, so kx and kz move too, but much less
    assert np.all(np.abs(cut.k[[0, 2]] - base.k[[0, 2]]) < 0.3 * (cut.k[1] - base.k[1]))


def test_device_not_put_back_is_flagged_by_the_closure_residual():
    rec, truth = simulate(14, noise=0.03, script=protocol(extra_after_y=Motion((8.0, 0.0, 0.0), 0.5)))
    motion = next(s for s in truth.stages if s.kind == "motion")
    res = calibrate_paper(rec, stages=protocol_stages(truth.stages, y_end_stage=motion))
    assert 6.0 < res.residuals["y"]["closure_deg"] < 10.0
    assert res.residuals["x"]["closure_deg"] < 1.0
    assert any(w.startswith("turn about y") for w in res.warnings)
    assert not any(w.startswith("turn about x") for w in res.warnings)


def test_warnings_for_saturation_and_wrong_units():
    rec, truth = simulate(15, noise=0.03, full_scale_dps=120.0)
    assert any("saturated" in s.flags for s in truth.stages)
    res = calibrate_paper(rec, stages=protocol_stages(truth.stages))
    assert any("full scale" in w for w in res.warnings)

    rec, truth = simulate(16, noise=0.03)
    in_rad = Recording(rec.t, np.radians(rec.gyro))  # a device that reports rad/s
    res = calibrate_paper(in_rad, stages=protocol_stages(truth.stages))
    np.testing.assert_allclose(res.k, np.degrees(truth.k), rtol=1e-3)
    assert any("far from 1" in w and "deg/s" in w for w in res.warnings)


def test_bad_input_raises_clear_errors():
    rec, truth = simulate(13, noise=0.03)
    stages = protocol_stages(truth.stages)
    bad = rec.gyro.copy()
    bad[500, 1] = np.nan
    with pytest.raises(RecordingError, match="NaN"):
        calibrate_paper(Recording(rec.t, bad), stages=stages)
    no_z = ProtocolStages(still0=stages.still0, turns={a: stages.turns[a] for a in "xy"}, stills=[])
    with pytest.raises(ProtocolError, match="about z"):
        calibrate_paper(rec, stages=no_z)
    xy_only = ProtocolScript((Still(3.0), Turn("x"), Still(3.0), Turn("y"), Still(3.0)))
    with pytest.raises(ProtocolError):
        calibrate_paper(simulate(13, noise=0.03, script=xy_only)[0])
    still0 = np.array([[stages.still0.start, stages.still0.end]])
    turns = [(s.start, s.end) for s in stages.turns.values()]
    with pytest.raises(RecordingError, match="start < end"):
        algorithm1_batch(rec.gyro[None], 1.0 / FS, still0, np.array([[turns[0], turns[1], (10, 5)]]))
    with pytest.raises(RecordingError, match="shape"):
        algorithm1_batch(rec.gyro[None], 1.0 / FS, still0, np.array([turns[:2]]))


# --------------------------------------------------------------------------------------------- the bench


def test_small_paper_sim_gives_a_table_json_and_a_box_plot(tmp_path):
    png = tmp_path / "fig7.png"
    report = paper_sim(sets=2, runs_per_set=20, seed=4, progress=False, plot_path=png, workers=1)
    text = report.table()
    for name in ("kx", "ky", "kz", "bx", "by", "bz", "noise 0.03", "noise 0.15", "wall time"):
        assert name in text
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    d = json.loads(json.dumps(report.to_dict()))
    assert [(r["noise"], r["method"]) for r in d["results"]] == [(0.03, "paper"), (0.15, "paper")]
    errs = report.errors[("paper", 0.15)]
    assert errs.shape == (40, 6)
    row = d["results"][1]["params"]["bx"]
    assert row["median"] == pytest.approx(float(np.median(errs[:, 3])))
    assert row["abs_p95"] == pytest.approx(float(np.percentile(np.abs(errs[:, 3]), 95)))
    assert d["results"][0]["failed"] == 0 and d["results"][0]["iterations"]["max"] <= 10


def offset_estimator(batch):
    """A stand-in estimator with known errors: truth + 0.01 on k, truth - 0.02 on b."""
    return batch.k_true + 0.01, batch.b_true - 0.02


def test_registered_methods_run_in_worker_processes_with_the_same_results(monkeypatch):
    monkeypatch.setitem(registry._BATCH_ADDED, "offset", offset_estimator)
    kwargs = dict(sets=2, runs_per_set=10, noise_levels=(0.03,), methods=("paper", "offset"), seed=3, progress=False)
    one = paper_sim(workers=1, **kwargs)
    two = paper_sim(workers=2, **kwargs)
    np.testing.assert_array_equal(one.errors[("paper", 0.03)], two.errors[("paper", 0.03)])
    np.testing.assert_allclose(two.errors[("offset", 0.03)], np.tile([0.01] * 3 + [-0.02] * 3, (20, 1)), atol=1e-12)
    assert "method offset" in two.table()


def test_register_batch_method_and_unknown_methods(monkeypatch):
    monkeypatch.setattr(registry, "_BATCH_ADDED", {})
    register_batch_method("offset2", offset_estimator)
    assert "offset2" in registry.batch_methods() and {"paper", "closure"} <= set(registry.batch_methods())
    with pytest.raises(GyrocalError, match="unknown bench method 'nope'"):
        paper_sim(sets=1, runs_per_set=2, methods=("nope",), progress=False)
