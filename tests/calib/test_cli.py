"""The gyrocal command line, end to end, run as a user runs it (a subprocess of the installed script)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

# imucal's own Ferraris calibration of example_ferraris_session.csv, in the g = k m + b convention
# (../shared/data/real/README.md).
IMUCAL_K = np.array([0.97284, 1.01788, 1.00169])


def gyrocal(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    exe = Path(sys.executable).with_name("gyrocal")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "calib.cli.main"]
    env = {k: v for k, v in os.environ.items() if k != "GYROCAL_DEBUG"}
    return subprocess.run([*cmd, *args], capture_output=True, text=True, cwd=cwd, env=env, timeout=300)


def assert_user_error(proc: subprocess.CompletedProcess[str], code: int, *fragments: str) -> None:
    assert proc.returncode == code, proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    assert proc.stderr.startswith("gyrocal: error:"), proc.stderr
    for fragment in fragments:
        assert fragment in proc.stderr, proc.stderr


@pytest.fixture(scope="module")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    path = tmp_path_factory.mktemp("sim") / "sim.csv"
    proc = gyrocal("simulate", "--seed", "11", "--noise", "0.03", "-o", str(path), "--truth")
    assert proc.returncode == 0, proc.stderr
    return path, json.loads(proc.stdout)


@pytest.mark.parametrize("method", ["paper", "closure"])
def test_calibrate_simulated_json(simulated: tuple[Path, dict], method: str) -> None:
    path, truth = simulated
    proc = gyrocal("calibrate", str(path), "--method", method, "--json")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["method"] == method
    for key in ("k", "b", "method", "stages", "quality"):
        assert key in out
    turns = [s for s in out["stages"] if s["kind"] == "turn"]
    assert [t["axis"] for t in turns] == ["x", "y", "z"]
    for stage in out["stages"]:
        assert set(stage) >= {"kind", "start_s", "end_s", "axis", "angle_deg"}
    assert np.allclose(out["k"], truth["k"], atol=2e-3)
    assert np.allclose(out["b"], truth["b"], atol=2e-2)


def test_calibrate_summary_and_plot(simulated: tuple[Path, dict], tmp_path: Path) -> None:
    path, _ = simulated
    png = tmp_path / "cal.png"
    proc = gyrocal("calibrate", str(path), "--plot", str(png))
    assert proc.returncode == 0, proc.stderr
    assert "k_x" in proc.stdout and "b_z" in proc.stdout and "turn" in proc.stdout
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_calibrate_real_imucal_session(ferraris_csv: Path) -> None:
    """The real third-party session: three turns found without the labels, k as imucal's."""
    proc = gyrocal("calibrate", str(ferraris_csv), "--fs", "102.4", "--json")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    turns = [s for s in out["stages"] if s["kind"] == "turn"]
    assert [t["axis"] for t in turns] == ["x", "y", "z"]
    assert all(t["angle_deg"] < 0 for t in turns)  # clockwise turns
    assert np.max(np.abs(np.array(out["k"]) - IMUCAL_K)) <= 5e-4


def test_calibrate_imu_tk_session_summary(real_data: Path) -> None:
    """imu_tk's two files from the command line: the re-orientations found and used, each with its gravity residual, and
    the summary says how far each kind of constraint is from its noise, the accelerometer's noise floor, the gyro's
    noise while moving and which rests were still settling."""
    folder = real_data / "imu_tk"
    proc = gyrocal("calibrate", str(folder / "xsens_gyro.mat"), "--layout", "imu_tk", "--accel", str(folder / "xsens_acc.mat"))
    assert proc.returncode == 0, proc.stderr
    assert "used: multi-position" in proc.stdout
    motions = [line.strip() for line in proc.stdout.splitlines() if line.strip().startswith("motion ")]
    assert [i for i, line in enumerate(motions) if "gravity residual" not in line] == [37]  # the last: no rest after it
    assert "motion    401.70 –   405.28 s  gravity residual 0.202 deg (chi-square 6.5 for 2)" in motions
    fit_line = next(line for line in proc.stdout.splitlines() if line.startswith("Chi-square per constraint"))
    assert "motions 67.6 / 63.6 = 1.06" in fit_line and "rests " in fit_line and "accelerometer magnitude " in fit_line
    assert "Accelerometer noise floor (rest means' scatter beyond white noise, measured on rest 0 over 7.9 s spans): " \
           "x none, y 0.062, z 0.084 mg" in proc.stdout
    assert "Gyroscope noise while moving over at rest (variance, 45-50 Hz): x 1.24, y 1.85, z 1.24" in proc.stdout
    assert "Rests still settling (counted in their noise): 6 of 38, largest drift 0.161 deg" in proc.stdout


def test_simulate_is_deterministic(tmp_path: Path) -> None:
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    assert gyrocal("simulate", "--seed", "5", "-o", str(a)).returncode == 0
    assert gyrocal("simulate", "--seed", "5", "-o", str(b)).returncode == 0
    assert a.read_text() == b.read_text()
    assert a.read_text().splitlines()[0].startswith("t,gx,gy,gz")


def test_missing_file(tmp_path: Path) -> None:
    assert_user_error(gyrocal("calibrate", str(tmp_path / "nope.csv")), 2, "nope.csv")


def test_garbage_file(tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("t,gx,gy,gz\n0,1,2,3\n0.01,1,banana,3\n")
    assert_user_error(gyrocal("calibrate", str(bad)), 2, "banana")


def test_imucal_layout_needs_fs(ferraris_csv: Path) -> None:
    assert_user_error(gyrocal("calibrate", str(ferraris_csv)), 2, "--fs")


def test_protocol_not_found_names_the_missing_stage(tmp_path: Path) -> None:
    """A recording that only rests: valid input, but no turn; exit 3 and say what is missing."""
    rest = tmp_path / "rest.csv"
    t = np.arange(0, 20, 1 / 104)
    rng = np.random.default_rng(0)
    g = rng.normal(0, 0.03, (t.size, 3)) + [0.5, -0.2, 0.1]
    np.savetxt(rest, np.column_stack([t, g]), delimiter=",", header="t,gx,gy,gz", comments="")
    proc = gyrocal("calibrate", str(rest))
    assert_user_error(proc, 3, "turn")


def test_bad_arguments_are_usage_errors() -> None:
    proc = gyrocal("calibrate")
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr


def test_bench_paper_sim_small(tmp_path: Path) -> None:
    png = tmp_path / "fig7.png"
    proc = gyrocal("bench", "paper-sim", "--sets", "2", "--runs-per-set", "20", "--plot", str(png),
                   "--no-progress", "--workers", "1")
    assert proc.returncode == 0, proc.stderr
    assert "paper" in proc.stdout and "closure" in proc.stdout
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_a_refused_recording_says_why_in_json_and_in_a_plot(tmp_path: Path) -> None:
    still = tmp_path / "still.csv"
    rows = "".join(f"{i / 100:.2f},0.01,-0.02,0.0\n" for i in range(600))
    still.write_text("t,gx,gy,gz\n" + rows)
    plot = tmp_path / "stages.png"
    proc = gyrocal("calibrate", str(still), "--json", "--plot", str(plot))
    assert proc.returncode == 3, proc.stderr
    error = json.loads(proc.stdout)["error"]
    assert error["code"] == "turn_missing" and "no turn about x" in error["message"]
    assert [s["kind"] for s in error["stages"]] == ["still"] and error["stages"][0]["end_s"] > 5.0
    assert plot.stat().st_size > 10_000 and plot.read_bytes()[:4] == b"\x89PNG"
    assert "stages found are drawn" in proc.stderr


def test_an_unreadable_recording_is_a_json_error_too(tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("hello world\n")
    proc = gyrocal("calibrate", str(bad), "--json")
    assert proc.returncode == 2
    error = json.loads(proc.stdout)["error"]
    assert error["code"] == "bad_recording" and "this is not a recording" in error["message"]
    assert_user_error(proc, 2, "this is not a recording", "one row per sample")


def test_a_plot_into_a_missing_folder_is_refused_before_any_work(simulated: tuple[Path, dict], tmp_path: Path) -> None:
    path, _ = simulated
    proc = gyrocal("calibrate", str(path), "--plot", str(tmp_path / "nowhere" / "p.png"))
    assert_user_error(proc, 2, "does not exist; create it or choose another path")


@pytest.mark.parametrize("fs", ["10", "1000"])
def test_a_wrong_sample_rate_is_named(ferraris_csv: Path, fs: str) -> None:
    proc = gyrocal("calibrate", str(ferraris_csv), "--fs", fs, "--json")
    assert proc.returncode == 3
    error = json.loads(proc.stdout)["error"]
    assert error["code"] == "sample_rate_suspect"
    assert f"read at 102.4 Hz instead of {fs} Hz" in error["message"] and "--fs 102.4" in error["message"]


def test_a_hand_held_recording_is_told_it_has_no_rest(real_data: Path) -> None:
    proc = gyrocal("calibrate", str(real_data / "sunsided" / "sunsided_xyz_uniform.csv"), "--json")
    assert proc.returncode == 3
    error = json.loads(proc.stdout)["error"]
    assert error["code"] == "no_rest"
    assert "no rest anywhere" in error["message"] and "deg/s, where a gyroscope lying on a table" in error["message"]


def test_effects_lists_the_catalogue_with_its_values_and_ranges() -> None:
    from calib.effects import CATALOGUE, EFFECTS

    proc = gyrocal("effects", "--json")
    assert proc.returncode == 0, proc.stderr
    rows = json.loads(proc.stdout)
    assert [r["name"] for r in rows] == list(CATALOGUE)
    for r in rows:
        assert r["value"] == EFFECTS[r["name"]].usage and r["revealed_by"]
        assert 0 < r["drawn"]["low"] < r["drawn"]["high"]
    text = gyrocal("effects")
    assert text.returncode == 0 and "clock_error=E" in text.stdout


def test_diagnose_takes_the_recording_options_calibrate_takes(ferraris_csv: Path, real_data: Path):
    sections = real_data / "imucal" / "example_ferraris_session_list.json"
    proc = gyrocal("diagnose", str(ferraris_csv), "--fs", "102.4", "--sections", str(sections), "--json")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["info"]["protocol"]["used"] == "ferraris"
    assert sorted(out["info"]["protocol"]["found"]["poses"]) == ["x_a", "x_p", "y_a", "y_p", "z_a", "z_p"]
    assert out["nominal"]["stills"] == 6 and out["nominal"]["turns"] == 3  # the labelled sections, not detection
    refused = gyrocal("diagnose", str(ferraris_csv), "--fs", "102.4", "--protocol", "multi-position", "--sections",
                      str(sections), "--json")
    assert_user_error(refused, 3, "re-orientations needs at least 6")
    assert_user_error(gyrocal("diagnose", str(ferraris_csv), "--layout", "imu_tk"), 2, "--accel FILE")
