"""Every refusal of a readable recording: `gyrocal calibrate --json` prints `{"error": {...}}` on stdout with the
refusal's code and exits 3, whichever stage refused it (stage detection, the protocol, the estimator)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from calib.cli.main import EXIT_PROTOCOL, main
from calib.errors import REFUSAL_CODES, CalibrationError, GyrocalError
from calib.io.readers import write_native_csv
from calib.simulator import simulate
from calib.simulator.lab_scripts import multi_position_script
from calib.simulator.protocol import Motion, ProtocolScript, Still, Turn


def _write(rec, path: Path) -> Path:  # noqa: ANN001
    with path.open("w") as f:
        write_native_csv(rec, f)
    return path


def _paper(tmp: Path, *segments) -> Path:  # noqa: ANN002
    rec, _ = simulate(1, noise=0.03, script=ProtocolScript(tuple(segments)))
    return _write(rec, tmp / "rec.csv")


def turn_missing(tmp: Path, real: Path) -> list[str]:
    still = tmp / "still.csv"
    still.write_text("t,gx,gy,gz\n" + "".join(f"{i / 100:.2f},0.01,-0.02,0.0\n" for i in range(600)))
    return [str(still)]


def still_missing(tmp: Path, real: Path) -> list[str]:
    return [str(_paper(tmp, Still(1.2), Turn("x", 360.0), Still(2.0), Turn("y", 360.0), Still(2.0), Turn("z", 360.0),
                       Still(2.0)))]


def no_rest(tmp: Path, real: Path) -> list[str]:
    return [str(real / "sunsided" / "sunsided_xyz_uniform.csv")]


def protocol_not_found(tmp: Path, real: Path) -> list[str]:
    rec, _ = simulate(1, noise=0.03)
    return [str(_write(rec, tmp / "paper.csv")), "--protocol", "ferraris"]


def _multi_position(tmp: Path, **kwargs) -> Path:  # noqa: ANN003
    rng = np.random.default_rng(3)
    rec, _ = simulate(3, noise=0.05, fs=100.0, script=multi_position_script(rng, n=8, first_rest_s=10.0, **kwargs))
    return _write(rec, tmp / "mp.csv")


def sections_incomplete(tmp: Path, real: Path) -> list[str]:
    path = _multi_position(tmp)
    sections = tmp / "sections.json"
    sections.write_text(json.dumps([{"label": "still", "start": 0, "end": 500}, {"label": "still_2", "start": 500, "end": 900}]))
    return [str(path), "--protocol", "multi-position", "--sections", str(sections)]


def not_closed(tmp: Path, real: Path) -> list[str]:
    # the x turn runs on into a 70 degree twist before the device rests: it cannot end where it began
    return [str(_paper(tmp, Still(3.0), Turn("x", 360.0), Motion((0.0, 0.0, 70.0), 1.0), Still(2.0), Turn("y", 360.0),
                       Still(2.0), Turn("z", 360.0), Still(2.0)))]


def accelerometer_not_determined(tmp: Path, real: Path) -> list[str]:
    # every rest in one pose (flat), taken as the multi-position protocol
    return [str(_multi_position(tmp, vertical_only=True)), "--protocol", "multi-position"]


FROM_RECORDINGS = {f.__name__: f for f in (turn_missing, still_missing, no_rest, protocol_not_found, sections_incomplete,
                                           not_closed, accelerometer_not_determined)}
# refusals another test already drives through the installed command, JSON and exit code included
IN_OTHER_TESTS = {"sample_rate_suspect": "tests/calib/test_cli.py::test_a_wrong_sample_rate_is_named",
                  "not_one_motion": "tests/calib/test_kit.py::test_recordings_that_are_not_one_kit_are_refused_with_what_to_do",
                  "not_a_rest": "tests/calib/test_noise.py::test_a_recording_that_moves_is_refused_with_when",
                  "rest_too_short": "tests/calib/test_noise.py::test_a_short_rest_is_refused_with_how_long_it_must_be"}
# refusals no recording of a few seconds provokes reliably: the estimator's refusal raised where it stands
FROM_THE_ESTIMATOR = {
    "not_determined": CalibrationError("the re-orientations do not determine every entry of K"),
    "reorientations_disagree": CalibrationError("gravity still 5 deg off", code="reorientations_disagree"),
    "not_calibrated": GyrocalError("some other reason the estimator gave"),
}


def _refusal(args: list[str], capsys: pytest.CaptureFixture[str]) -> dict:
    assert main(["calibrate", *args, "--json"]) == EXIT_PROTOCOL
    out, err = capsys.readouterr()
    error = json.loads(out)["error"]
    assert err.startswith("gyrocal: error: ") and error["message"] in err
    return error


@pytest.mark.parametrize("code", sorted(FROM_RECORDINGS))
def test_a_refused_recording_prints_its_code_as_json_and_exits_3(code: str, tmp_path: Path, real_data: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    error = _refusal(FROM_RECORDINGS[code](tmp_path, real_data), capsys)
    assert error["code"] == code, error["message"]
    assert error["message"]


@pytest.mark.parametrize("code", sorted(FROM_THE_ESTIMATOR))
def test_an_estimator_refusal_prints_its_code_as_json_and_exits_3(code: str, tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str],
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    rec, _ = simulate(1, noise=0.03)
    path = _write(rec, tmp_path / "paper.csv")

    def refuse(*_args, **_kwargs):  # noqa: ANN002, ANN003, ANN202
        raise FROM_THE_ESTIMATOR[code]

    monkeypatch.setattr("calib.pipeline.calibrate_protocol", refuse)
    error = _refusal([str(path)], capsys)
    assert error["code"] == code
    assert [s["kind"] for s in error["stages"] if s["kind"] == "turn"] == ["turn"] * 3  # the stages found are shown


def test_every_refusal_code_is_tested() -> None:
    assert set(FROM_RECORDINGS) | set(FROM_THE_ESTIMATOR) | set(IN_OTHER_TESTS) == set(REFUSAL_CODES)


def test_an_unreadable_file_is_a_usage_error_with_json_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("hello world\n")
    assert main(["calibrate", str(bad), "--json"]) == 2
    assert json.loads(capsys.readouterr().out)["error"]["code"] == "bad_recording"
