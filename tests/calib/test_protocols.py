"""Protocols beyond the paper's: labelled sections, Ferraris' method, protocol recognition, the rate table, and the
comparison of methods; checked against imucal's published results on its own recordings."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from test_cli import IMUCAL_K, assert_user_error, gyrocal

from calib.errors import GyrocalError, ProtocolError, RecordingError
from calib.estimators.ferraris import calibrate_ferraris, find_poses
from calib.io.readers import read_recording
from calib.io.sections import parse_sections, read_sections, sections_from_labels, stages_from_sections
from calib.pipeline import calibrate, calibrate_protocol
from calib.simulator import SensorParams, simulate
from calib.simulator.lab_scripts import ferraris_script, inclined_script, rate_table_script
from calib.stages.detector import detect_stages
from calib.stages.recognise import recognise

# imucal's Ferraris result for annotated_session.csv (counts; ../shared/data/real/README.md)
ANNOTATED_K_G = np.array([16.6777, 16.1879, 16.2534])  # counts per deg/s
ANNOTATED_B_G = np.array([1.9607, -4.4728, -3.6512])  # counts
NOMINAL_COUNTS = 16.4  # counts per deg/s: the README's nominal sensitivity, to state k as a dimensionless ratio
IMUCAL_B_G = np.array([-0.59967, -0.36984, 0.05877])  # example session, deg/s


@pytest.fixture(scope="module")
def annotated(real_data: Path):
    return read_recording(real_data / "imucal" / "annotated_session.csv", fs=204.8,
                          gyro_counts_per_dps=NOMINAL_COUNTS, accel_counts_per_g=2048.0)


@pytest.fixture(scope="module")
def example(ferraris_csv: Path):
    return read_recording(ferraris_csv, fs=102.4)


@pytest.fixture(scope="module")
def example_sections(real_data: Path, example):
    return read_sections(real_data / "imucal" / "example_ferraris_session_list.json", len(example))


# -- sections --------------------------------------------------------------------------------------
def test_the_part_column_becomes_sections_in_recording_order(annotated) -> None:
    labels = [s.label for s in annotated.meta.sections]
    assert labels == ["x_p", "x_a", "y_p", "y_a", "z_p", "z_a", "x_rot", "y_rot", "z_rot"]
    assert annotated.meta.sections[0].start == 0 and annotated.meta.sections[-1].end == len(annotated)
    assert all(a.end == b.start for a, b in zip(annotated.meta.sections, annotated.meta.sections[1:], strict=False))


def test_sections_from_labels_are_the_runs() -> None:
    secs = sections_from_labels(np.array(["still", "still", "x_rot", "x_rot", "x_rot", "still_2"]))
    assert [(s.label, s.start, s.end, s.kind, s.axis) for s in secs] == [
        ("still", 0, 2, "still", None), ("x_rot", 2, 5, "turn", "x"), ("still_2", 5, 6, "still", None)]


@pytest.mark.parametrize(("text", "fragment"), [
    ("{", "is not valid JSON"),
    ("[]", "holds no sections"),
    ('{"x_p": {"start": 0, "end": 50}, "spin": {"start": 60, "end": 70}}', "unknown section label 'spin'"),
    ('{"x_p": {"start": 0, "end": 5000}}', "not inside the recording's 100 samples"),
    ('{"x_p": {"start": "a", "end": 5}}', "whole sample positions"),
    ('{"x_p": {"start": 0, "end": 50}, "x_a": {"start": 40, "end": 60}}', "overlap"),
])
def test_a_bad_section_list_says_what_is_wrong(text: str, fragment: str) -> None:
    with pytest.raises(RecordingError, match=fragment):
        parse_sections(text, 100)


def test_labelled_turns_measure_their_angle(annotated) -> None:
    stages = stages_from_sections(annotated, annotated.meta.sections)
    turns = [s for s in stages if s.kind == "turn"]
    assert [s.axis for s in turns] == ["x", "y", "z"]
    assert all(340 < s.angle_deg < 380 for s in turns)  # counter-clockwise, about +360 each


# -- against imucal's published results ------------------------------------------------------------
def test_ferraris_method_reproduces_imucal_on_the_annotated_session(annotated) -> None:
    f = calibrate_ferraris(annotated, stages_from_sections(annotated, annotated.meta.sections)).quality["ferraris"]
    np.testing.assert_allclose(np.array(f["K_g"]) * NOMINAL_COUNTS, ANNOTATED_K_G, atol=1e-4)
    np.testing.assert_allclose(np.array(f["b_g"]) * NOMINAL_COUNTS, ANNOTATED_B_G, atol=1e-4)


def test_ferraris_method_reproduces_imucal_on_the_example_session(example, example_sections) -> None:
    res = calibrate_ferraris(example, stages_from_sections(example, example_sections))
    np.testing.assert_allclose(res.k, IMUCAL_K, atol=2e-5)
    np.testing.assert_allclose(res.quality["ferraris"]["b_g"], IMUCAL_B_G, atol=2e-5)
    k_ga = np.abs(np.array(res.quality["ferraris"]["K_ga"])).max() / 9.80665  # README: up to 6e-4 (deg/s)/(m/s^2)
    assert 5e-4 < k_ga < 7e-4


def test_gyrocal_given_the_labels_is_within_5e_4_of_imucal(annotated) -> None:
    res, used = calibrate_protocol(annotated)  # the file's own labels
    assert used == "ferraris" and res.method == "closure"
    assert res.quality["protocol"]["sections"] == 9
    assert np.abs(res.k - NOMINAL_COUNTS / ANNOTATED_K_G).max() < 5e-4
    assert np.all(res.k_std < 5e-4)


def test_gyrocal_on_the_example_session_with_and_without_its_section_list(example, example_sections) -> None:
    labelled, used = calibrate_protocol(example, sections=example_sections)
    detected, found = calibrate_protocol(example)
    assert used == found == "ferraris"
    assert detected.quality["protocol"]["found"]["poses"] == ["x_p", "x_a", "y_p", "y_a", "z_p", "z_a"]
    for res in (labelled, detected):
        assert np.abs(res.k - IMUCAL_K).max() < 5e-4


def test_multi_position_refuses_sections_that_cut_the_motions_out(annotated) -> None:
    with pytest.raises(GyrocalError, match="do not hold every motion between two rests"):
        calibrate_protocol(annotated, "multi-position")


# -- recognition -----------------------------------------------------------------------------------
def test_each_simulated_protocol_is_recognised() -> None:
    rng = np.random.default_rng(3)
    cases = {
        "paper": simulate(3, noise=0.05)[0],
        "ferraris": simulate(4, noise=0.05, script=ferraris_script(rng))[0],
        "multi-position": simulate(5, noise=0.05, script=inclined_script(rng))[0],
    }
    for name, rec in cases.items():
        assert recognise(rec, detect_stages(rec)).name == name
        assert calibrate_protocol(rec)[1] == name


def test_the_hand_held_recording_is_refused_with_the_reason(real_data: Path) -> None:
    rec = read_recording(real_data / "sunsided" / "sunsided_xyz_uniform.csv")
    assert recognise(rec, detect_stages(rec)).name == "hand-held"
    with pytest.raises(ProtocolError, match="held in the hand throughout") as err:
        calibrate_protocol(rec)
    assert err.value.code == "no_rest" and "offset cannot be told apart from its scale factors" in str(err.value)


def test_asking_for_the_wrong_protocol_points_to_the_one_found() -> None:
    rng = np.random.default_rng(6)
    rec, _ = simulate(6, noise=0.05, script=inclined_script(rng))
    with pytest.raises(ProtocolError, match="calibrate it with --protocol multi-position"):
        calibrate_protocol(rec, "paper")


# -- the other methods on simulated sensors --------------------------------------------------------
def test_ferraris_poses_and_method_on_a_simulated_ferraris_protocol() -> None:
    rng = np.random.default_rng(1)
    rec, truth = simulate(1, noise=0.03, script=ferraris_script(rng))
    stages = detect_stages(rec)
    assert list(find_poses(rec, [s for s in stages if s.kind == "still"])) == ["x_p", "x_a", "y_p", "y_a", "z_p", "z_a"]
    ferraris = calibrate_ferraris(rec, stages)
    ours = calibrate(rec, stages=stages)
    assert np.abs(ferraris.k - truth.k).max() < 0.01  # hand turns' tilted axes cost Ferraris' row norms up to ~0.5 %
    assert np.abs(ours.k - truth.k).max() < 1e-3 and np.abs(ours.b - truth.b).max() < 0.01


def test_ferraris_method_refuses_without_the_six_poses() -> None:
    rec, _ = simulate(2, noise=0.03)
    with pytest.raises(ProtocolError, match="missing: x_p"):
        calibrate_ferraris(rec)


def test_the_rate_table_recovers_k_and_b_from_known_runs() -> None:
    from calib.estimators.rate_table import calibrate_rate_table
    from calib.studies.methods import FS, _table_runs

    params = SensorParams(np.array([1.05, 0.97, 1.1]), np.array([0.5, -1.0, 2.0]))
    rec, truth = simulate(8, 0.05, FS, params, rate_table_script((20.0, 50.0, 100.0), 10.0))
    res = calibrate_rate_table(rec, _table_runs(truth, (20.0, 50.0, 100.0), 10.0))
    assert np.abs(res.k - params.k).max() < 2e-4 and np.abs(res.b - params.b).max() < 0.01
    assert np.all(res.k_std > 0)


def test_bench_methods_runs_every_method_and_draws_the_plot(tmp_path: Path) -> None:
    plot = tmp_path / "methods.png"
    proc = gyrocal("bench", "methods", "--runs", "1", "--noise", "0.03", "--plot", str(plot), "--json", "--no-progress")
    assert proc.returncode == 0, proc.stderr
    rows = json.loads(proc.stdout)["rows"]
    assert {r["method"] for r in rows} == {"turntable", "accelerometer-aided", "servomotor", "ferraris", "paper", "gyrocal"}
    assert all(r["failed"] == 0 and r["runs"] == 1 for r in rows)
    by = {(r["sensor"], r["method"]): r for r in rows}
    for sensor in ("LSM9DS1", "ICM-20948"):
        assert max(by[(sensor, "turntable")]["median_abs_error"][p] for p in ("kx", "ky", "kz")) < 1e-3
        assert max(by[(sensor, "gyrocal")]["median_abs_error"][p] for p in ("kx", "ky", "kz")) < 2e-3
        assert by[(sensor, "accelerometer-aided")]["protocol_s"] > 10 * by[(sensor, "gyrocal")]["protocol_s"]
    assert plot.read_bytes()[:4] == b"\x89PNG"


# -- the command line ------------------------------------------------------------------------------
def test_cli_calibrates_the_annotated_counts_file_with_its_labels(real_data: Path) -> None:
    proc = gyrocal("calibrate", str(real_data / "imucal" / "annotated_session.csv"), "--fs", "204.8",
                   "--gyro-counts-per-dps", "16.4", "--accel-counts-per-g", "2048", "--json")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["protocol"] == "ferraris" and out["quality"]["protocol"]["found"]["name"] == "ferraris"
    assert np.abs(np.array(out["k"]) - NOMINAL_COUNTS / ANNOTATED_K_G).max() < 5e-4
    acc = out["accelerometer"]  # six rests, six unknowns: the fit has no redundancy to vouch for the scale factors
    assert acc["n_rests"] == 6 and acc["identified"] == ["o_x", "o_y", "o_z"] and "scale factors" in acc["note"]


def test_cli_sections_and_ferraris_method(real_data: Path, ferraris_csv: Path) -> None:
    proc = gyrocal("calibrate", str(ferraris_csv), "--fs", "102.4", "--sections",
                   str(real_data / "imucal" / "example_ferraris_session_list.json"), "--method", "ferraris")
    assert proc.returncode == 0, proc.stderr
    assert "Protocol found: ferraris" in proc.stdout and "(9 labelled sections)" in proc.stdout


def test_cli_bad_sections_and_a_stray_accel_file_are_clear_errors(tmp_path: Path, ferraris_csv: Path) -> None:
    bad = tmp_path / "sections.json"
    bad.write_text('{"x_p": {"start": 0, "end": 99999999}}')
    proc = gyrocal("calibrate", str(ferraris_csv), "--fs", "102.4", "--sections", str(bad), "--json")
    assert proc.returncode == 2 and json.loads(proc.stdout)["error"]["code"] == "bad_sections"
    assert_user_error(gyrocal("calibrate", str(ferraris_csv), "--fs", "102.4", "--accel", str(bad)), 2,
                      "--accel FILE names imu_tk's separate accelerometer file")
