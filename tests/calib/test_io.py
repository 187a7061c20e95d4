"""Reading, writing and validating recordings (calib.io.readers, calib.io.validation)."""

from __future__ import annotations

import csv
import io
import json
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from calib.errors import RecordingError
from calib.io.readers import parse_recording_text, read_recording, validate_recording, write_native_csv
from calib.recording import Recording, RecordingMeta
from calib.units import STANDARD_GRAVITY

REAL = Path("/work/shared/data/real/imucal")
FERRARIS = REAL / "example_ferraris_session.csv"
ANNOTATED = REAL / "annotated_session.csv"


def _file_rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _recording(n: int = 50, fs: float = 100.0, accel: bool = True, seq: bool = True, temp: bool = True) -> Recording:
    rng = np.random.default_rng(n)
    return Recording(
        t=0.25 + np.arange(n) / fs,
        gyro=rng.normal(0.0, 30.0, (n, 3)),
        accel=rng.normal(0.0, 0.5, (n, 3)) if accel else None,
        seq=np.arange(n) * 2 + 7 if seq else None,
        temp=25.0 + rng.normal(0.0, 0.1, n) if temp else None,
    )


def _csv(text: str) -> str:
    return "\n".join(line.strip() for line in text.strip().splitlines()) + "\n"


def _error(text: str, **kwargs: object) -> str:
    with pytest.raises(RecordingError) as exc:
        parse_recording_text(_csv(text), source="rec.csv", **kwargs)
    return str(exc.value)


# --- real third-party recordings -------------------------------------------------------------------


def test_imucal_ferraris_session_reads_with_its_sample_rate() -> None:
    rec = read_recording(FERRARIS, fs=102.4)
    rows = _file_rows(FERRARIS)
    assert len(rec) == len(rows) == 10376
    assert rec.meta.source == FERRARIS.name
    assert rec.meta.sample_rate_hz == 102.4
    assert rec.fs == pytest.approx(102.4)
    assert rec.duration_s == pytest.approx(101.3, abs=0.1)
    np.testing.assert_array_equal(rec.seq, np.arange(10376))
    np.testing.assert_allclose(np.diff(rec.t), 1 / 102.4)
    last = rows[-1]
    np.testing.assert_array_equal(rec.gyro[-1], [float(last[c]) for c in ("gyr_x", "gyr_y", "gyr_z")])
    np.testing.assert_allclose(rec.accel[-1], [float(last[c]) / STANDARD_GRAVITY for c in ("acc_x", "acc_y", "acc_z")])


def test_imucal_ferraris_accelerometer_reads_one_g_in_every_static_pose() -> None:
    rec = read_recording(FERRARIS, fs=102.4)
    sections = json.loads((REAL / "example_ferraris_session_list.json").read_text())
    for axis, j in (("x", 0), ("y", 1), ("z", 2)):
        up = rec.accel[sections[f"{axis}_p"]["start"] : sections[f"{axis}_p"]["end"]]
        down = rec.accel[sections[f"{axis}_a"]["start"] : sections[f"{axis}_a"]["end"]]
        # this accelerometer has offsets of about 0.06 g, so compare the half difference of opposite poses
        assert (up[:, j].mean() - down[:, j].mean()) / 2 == pytest.approx(1.0, abs=0.03)
        for pose in (up, down):
            assert np.linalg.norm(pose, axis=1).mean() == pytest.approx(1.0, abs=0.1)


def test_imucal_without_sample_rate_asks_for_fs() -> None:
    with pytest.raises(RecordingError, match="pass it as fs"):
        read_recording(FERRARIS)


def test_imucal_annotated_session_needs_sensitivities() -> None:
    with pytest.raises(RecordingError, match="gyro_counts_per_dps and accel_counts_per_g"):
        read_recording(ANNOTATED, fs=204.8)


def test_imucal_annotated_session_is_put_back_in_sample_order_and_scaled() -> None:
    rec = read_recording(ANNOTATED, fs=204.8, gyro_counts_per_dps=16.4, accel_counts_per_g=2048)
    rows = _file_rows(ANNOTATED)
    assert len(rec) == len(rows)
    np.testing.assert_array_equal(rec.seq, np.sort([int(r["samples"]) for r in rows]))
    np.testing.assert_array_equal(rec.t, rec.seq / 204.8)
    first = next(r for r in rows if int(r["samples"]) == rec.seq[0])
    np.testing.assert_allclose(rec.gyro[0], [float(first[c]) / 16.4 for c in ("gyr_x", "gyr_y", "gyr_z")])
    still = rec.accel[rec.seq < 1000]  # the first labelled section is a static pose
    assert np.linalg.norm(still, axis=1).mean() == pytest.approx(1.0, abs=0.05)


# --- native layout ---------------------------------------------------------------------------------


@pytest.mark.parametrize("channels", [(True, True, True), (False, False, False), (True, False, True), (False, True, False)])
def test_native_round_trip_through_file(tmp_path: Path, channels: tuple[bool, bool, bool]) -> None:
    accel, seq, temp = channels
    rec = _recording(accel=accel, seq=seq, temp=temp)
    path = tmp_path / "walk.csv"
    write_native_csv(rec, path)
    header = path.read_text().splitlines()[0].split(",")
    assert header == ["t", "gx", "gy", "gz"] + ["ax", "ay", "az"] * accel + ["seq"] * seq + ["temp"] * temp
    back = read_recording(path)
    assert back.meta.source == "walk.csv"
    for name in ("t", "gyro", "accel", "seq", "temp"):
        a, b = getattr(rec, name), getattr(back, name)
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(a, b)


def test_native_writes_seq_as_integers() -> None:
    buf = io.StringIO()
    write_native_csv(_recording(n=3, accel=False, temp=False), buf)
    rows = list(csv.DictReader(io.StringIO(buf.getvalue())))
    assert [r["seq"] for r in rows] == ["7", "9", "11"]


def test_native_column_order_is_free_and_other_columns_are_ignored() -> None:
    rec = parse_recording_text(
        _csv("""
        label,seq,gz,gy,gx,t,note
        rest,10,0.3,0.2,0.1,0.00,a b
        rest,11,0.6,0.5,0.4,0.01,
        """)
    )
    np.testing.assert_array_equal(rec.gyro, [[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]])
    np.testing.assert_array_equal(rec.t, [0.0, 0.01])
    np.testing.assert_array_equal(rec.seq, [10, 11])
    assert rec.accel is None and rec.temp is None


def test_native_accepts_bom_crlf_semicolons_blank_lines_and_comments() -> None:
    text = "\ufeff# exported by a logger\r\nt;gx;gy;gz\r\n0;1;2;3\r\n\r\n0.5;4;5;6\r\n"
    rec = parse_recording_text(text)
    np.testing.assert_array_equal(rec.gyro, [[1, 2, 3], [4, 5, 6]])
    assert rec.fs == pytest.approx(2.0)


def test_native_line_numbers_count_blank_lines() -> None:
    assert "line 5, column gy" in _error("t,gx,gy,gz\n0,0,0,0\n\n0.1,0,0,0\n0.2,0,x,0")


def test_native_fs_is_stored_and_checked_against_the_time_column() -> None:
    text = _csv("t,gx,gy,gz\n0,0,0,0\n0.01,0,0,0\n0.02,0,0,0")
    assert parse_recording_text(text, fs=101.0).meta.sample_rate_hz == 101.0
    assert parse_recording_text(text).meta.sample_rate_hz is None
    with pytest.raises(RecordingError, match=r"given as 110 Hz .* \(100 Hz\)"):
        parse_recording_text(text, fs=110)


def test_native_counter_wrap_around_is_unwrapped() -> None:
    rec = parse_recording_text(_csv("t,gx,gy,gz,seq\n0,0,0,0,65534\n0.1,0,0,0,65535\n0.2,0,0,0,0\n0.3,0,0,0,2"))
    np.testing.assert_array_equal(rec.seq, [65534, 65535, 65536, 65538])


def test_imucal_unnamed_index_column_and_optional_accelerometer() -> None:
    rec = parse_recording_text(_csv(",gyr_x,gyr_y,gyr_z\n4,1,2,3\n5,4,5,6"), fs=50)
    np.testing.assert_array_equal(rec.seq, [4, 5])
    np.testing.assert_allclose(rec.t, [0.08, 0.1])
    assert rec.accel is None


def test_imucal_without_index_uses_row_number() -> None:
    rec = parse_recording_text(_csv("gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n1,2,3,0,0,9.80665\n4,5,6,0,0,-9.80665"), fs=10)
    np.testing.assert_array_equal(rec.t, [0.0, 0.1])
    np.testing.assert_allclose(rec.accel, [[0, 0, 1], [0, 0, -1]])
    assert rec.seq is None


def test_upload_as_bytes_is_decoded() -> None:
    rec = parse_recording_text(b"t,gx,gy,gz\n0,1,2,3\n1,4,5,6\n", source="upload.csv")
    assert rec.meta.source == "upload.csv" and len(rec) == 2


# --- validation errors -----------------------------------------------------------------------------


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="does not exist"):
        read_recording(tmp_path / "nope.csv")


def test_directory(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="is a directory"):
        read_recording(tmp_path)


@pytest.mark.parametrize("data", [b"\x00\x01\x02GYRO\x00", b"t,gx,gy,gz\n0,0,0\x00,0\n"])
def test_binary_file(tmp_path: Path, data: bytes) -> None:
    path = tmp_path / "dump.bin"
    path.write_bytes(data)
    with pytest.raises(RecordingError, match="dump.bin is a binary file"):
        read_recording(path)


def test_non_utf8_file(tmp_path: Path) -> None:
    path = tmp_path / "latin.csv"
    path.write_bytes("t,gx,gy,gz,Temp °C\n0,0,0,0,1\n".encode("latin-1"))
    with pytest.raises(RecordingError, match=r"latin.csv is not UTF-8 text \(byte 0xb0 at offset 16\)"):
        read_recording(path)


@pytest.mark.parametrize("text", ["", "   \n\n", "# only a comment\n"])
def test_empty_file(text: str) -> None:
    with pytest.raises(RecordingError, match="rec.csv: the file is empty; expected a CSV with a header"):
        parse_recording_text(text, source="rec.csv")


def test_header_only() -> None:
    assert "header but no data rows" in _error("t,gx,gy,gz\n\n")


def test_missing_column_is_named_with_the_expected_header() -> None:
    msg = _error("t,gx,gy\n0,1,2")
    assert "missing column gz" in msg and "t,gx,gy,gz[,ax,ay,az][,seq][,temp]" in msg


def test_unknown_header_lists_all_missing_columns() -> None:
    msg = _error("time,x,y,z\n0,1,2,3")
    assert "missing columns t, gx, gy, gz" in msg and "the header has time, x, y, z" in msg


def test_imucal_missing_gyro_column() -> None:
    assert "missing column gyr_z" in _error("gyr_x,gyr_y,acc_x,acc_y,acc_z\n1,2,3,4,5", fs=100)


def test_header_of_numbers() -> None:
    assert "line 1 holds numbers, not column names" in _error("0,1,2,3\n0.1,1,2,3")


def test_partial_accelerometer() -> None:
    msg = _error("t,gx,gy,gz,ax\n0,0,0,0,1")
    assert "has ax but not ay, az" in msg


def test_duplicate_column() -> None:
    assert "column gx appears more than once" in _error("t,gx,gy,gz,gx\n0,0,0,0,0\n1,0,0,0,0")


@pytest.mark.parametrize(
    ("row", "expected"),
    [
        ("0.1,0,abc,0", "line 3, column gy: the cell holds 'abc', which is not a number"),
        ("0.1,,0,0", "line 3, column gx: the cell is empty"),
        ("0.1,0,0,0x1F", "line 3, column gz: the cell holds '0x1F'"),
    ],
)
def test_non_numeric_cell(row: str, expected: str) -> None:
    assert expected in _error(f"t,gx,gy,gz\n0,0,0,0\n{row}\n0.2,0,0,0")


def test_decimal_comma_is_reported() -> None:
    msg = _error("t;gx;gy;gz\n0;0;0;0\n0,1;0;0;1,5")
    assert "line 3, column t: the cell holds '0,1'" in msg and "'.' as the decimal point" in msg


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "1e400"])
def test_non_finite_value(value: str) -> None:
    msg = _error(f"t,gx,gy,gz\n0,0,0,0\n0.1,0,0,{value}")
    assert "line 3, column gz" in msg and "not a finite number" in msg


def test_ragged_rows() -> None:
    assert "line 3 has 5 fields but the header has 4" in _error("t,gx,gy,gz\n0,0,0,0\n0.1,0,0,0,0")
    assert "line 2 has 3 fields but the header has 4" in _error("t,gx,gy,gz\n0,0,0\n0.1,0,0,0")


@pytest.mark.parametrize(
    ("times", "expected"),
    [("0,0.1,0.1", "line 4, column t: the time repeats"), ("0,0.2,0.1", "line 4, column t: the time goes backwards")],
)
def test_time_must_strictly_increase(times: str, expected: str) -> None:
    rows = "\n".join(f"{t},0,0,0" for t in times.split(","))
    msg = _error(f"t,gx,gy,gz\n{rows}")
    assert expected in msg and "sort the rows" in msg


@pytest.mark.parametrize(("seq", "kind"), [("1,2,2", "repeats"), ("1,3,2", "goes backwards")])
def test_sample_counter_must_strictly_increase(seq: str, kind: str) -> None:
    rows = "\n".join(f"{i / 10},0,0,0,{s}" for i, s in enumerate(seq.split(",")))
    assert f"line 4, column seq: the sample counter {kind}" in _error(f"t,gx,gy,gz,seq\n{rows}")


def test_sample_counter_must_be_whole() -> None:
    assert "line 3, column seq: 1.5 is not a whole sample number" in _error("t,gx,gy,gz,seq\n0,0,0,0,1\n0.1,0,0,0,1.5")


def test_imucal_index_must_increase_when_not_grouped_by_label() -> None:
    msg = _error("n_samples,gyr_x,gyr_y,gyr_z\n0,0,0,0\n2,0,0,0\n1,0,0,0", fs=100)
    assert "line 4, column n_samples: the sample index goes backwards" in msg


def test_single_sample_has_no_sample_rate() -> None:
    msg = _error("t,gx,gy,gz\n0,0,0,0")
    assert "only 1 sample" in msg and "sample rate cannot be determined" in msg


def test_recording_too_short_for_the_protocol() -> None:
    rec = _recording(n=101, fs=100.0)
    validate_recording(rec, min_duration_s=0.5)
    with pytest.raises(RecordingError, match=r"lasts 1.0 s but the protocol needs at least 30 s"):
        validate_recording(rec, min_duration_s=30)


@pytest.mark.parametrize(
    ("column", "value", "expected"),
    [
        ("gx", "12000", "line 3, column gx: 12000 deg/s is beyond any sensor's range (limit +-10000 deg/s)"),
        ("ay", "-60", "line 3, column ay: -60 g is beyond any sensor's range (limit +-50 g)"),
        ("temp", "200", "line 3, column temp: temperature 200 C is outside -60..150 C"),
        ("temp", "-80", "line 3, column temp: temperature -80 C"),
    ],
)
def test_absurd_values(column: str, value: str, expected: str) -> None:
    names = ["t", "gx", "gy", "gz", "ax", "ay", "az", "temp"]
    good = {"t": "0", "gx": "0", "gy": "0", "gz": "0", "ax": "0", "ay": "0", "az": "1", "temp": "20"}
    bad = {**good, "t": "0.1", column: value}
    rows = [",".join(names), ",".join(good[c] for c in names), ",".join(bad[c] for c in names)]
    assert expected in _error("\n".join(rows))


@pytest.mark.parametrize("fs", [0.5, 20000, float("nan"), "fast"])
def test_absurd_stated_sample_rate(fs: object) -> None:
    assert "give fs in Hz" in _error("gyr_x,gyr_y,gyr_z\n0,0,0\n0,0,0", fs=fs)


def test_time_in_milliseconds_is_recognised() -> None:
    msg = _error("t,gx,gy,gz\n0,0,0,0\n10,0,0,0\n20,0,0,0")
    assert "0.1 Hz" in msg and "milliseconds" in msg


def test_unknown_layout() -> None:
    assert "unknown layout 'csv'" in _error("t,gx,gy,gz\n0,0,0,0", layout="csv")


def test_explicit_layout_must_match_the_header() -> None:
    assert "missing columns gyr_x, gyr_y, gyr_z" in _error("t,gx,gy,gz\n0,0,0,0\n1,0,0,0", layout="imucal", fs=1)


def test_sensitivities_rejected_for_files_in_physical_units() -> None:
    assert "leave them out" in _error("t,gx,gy,gz\n0,0,0,0\n1,0,0,0", gyro_counts_per_dps=16.4)


def test_sensitivities_must_be_positive() -> None:
    msg = _error("part,samples,gyr_x,gyr_y,gyr_z\na,0,1,1,1\na,1,1,1,1", fs=100, gyro_counts_per_dps=[16, -1, 16])
    assert "gyro_counts_per_dps must be a positive number" in msg


def test_validate_recording_names_the_sample_without_a_file() -> None:
    rec = _recording(n=5)
    rec.gyro[1, 1] = np.nan
    with pytest.raises(RecordingError, match=r"sample 2, column gyro y: value nan is not a finite number"):
        validate_recording(rec)


def test_validate_recording_checks_the_stated_rate() -> None:
    rec = _recording(n=20, fs=100.0).with_meta(sample_rate_hz=50.0)
    with pytest.raises(RecordingError, match="given as 50 Hz"):
        validate_recording(rec)


# --- property-based ---------------------------------------------------------------------------------

_floats = lambda lim: st.floats(-lim, lim, allow_nan=False, allow_infinity=False)  # noqa: E731


@st.composite
def recordings(draw: st.DrawFn) -> Recording:
    n = draw(st.integers(2, 40))
    t0 = draw(_floats(1e3))
    steps = draw(st.lists(st.floats(1e-3, 0.5), min_size=n - 1, max_size=n - 1))
    t = t0 + np.concatenate([[0.0], np.cumsum(steps)])
    vec = lambda lim: np.array(draw(st.lists(st.tuples(_floats(lim), _floats(lim), _floats(lim)), min_size=n, max_size=n)))  # noqa: E731
    gyro = vec(1e4)
    accel = vec(50.0) if draw(st.booleans()) else None
    seq = None
    if draw(st.booleans()):
        seq = draw(st.integers(-(2**40), 2**40)) + np.cumsum(draw(st.lists(st.integers(1, 1000), min_size=n, max_size=n)))
    temp = np.array(draw(st.lists(st.floats(-60, 150), min_size=n, max_size=n))) if draw(st.booleans()) else None
    return Recording(t, gyro, accel, seq, temp, RecordingMeta())


@settings(max_examples=150, deadline=None)
@given(recordings())
def test_random_recordings_round_trip(rec: Recording) -> None:
    buf = io.StringIO()
    write_native_csv(rec, buf)
    back = parse_recording_text(buf.getvalue())
    for name in ("t", "gyro", "accel", "seq", "temp"):
        a, b = getattr(rec, name), getattr(back, name)
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(a, b)


_COLUMNS = ["t", "gx", "gy", "gz", "ax", "ay", "az", "seq", "temp", "gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y",
            "acc_z", "n_samples", "part", "", "note"]
_CELLS = ["0", "1", "-1", "0.01", "1e3", "12000", "-61", "1.5", "nan", "inf", "1e400", "", " ", "abc", "x_p",
          "1e-320", "9007199254740993", "-0", "\t2", "0x10", "1_0", "\u0662", '"1"', "1,2", "#"]


_HEADERS = [
    ["t", "gx", "gy", "gz"],
    ["t", "gx", "gy", "gz", "ax", "ay", "az", "seq", "temp"],
    ["gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z"],
    ["n_samples", "gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z"],
    ["part", "samples", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"],
]


@st.composite
def csv_texts(draw: st.DrawFn) -> str:
    """CSV-shaped text: a layout's header with additions, rows that are mostly plausible, some mutated."""
    base = draw(st.one_of(st.sampled_from(_HEADERS), st.lists(st.sampled_from(_COLUMNS), max_size=10)))
    header = draw(st.permutations(base + draw(st.lists(st.sampled_from(_COLUMNS), max_size=2))))
    sep = draw(st.sampled_from([",", ",", ";", "\t"]))
    n = draw(st.integers(1, 8))
    rows = [[str(i)] * len(header) for i in range(n)]  # increasing whole numbers: a valid recording at 1 Hz
    for _ in range(draw(st.integers(0, 3))):
        if not rows:
            break
        row = draw(st.sampled_from(rows))
        action = draw(st.sampled_from(["cell", "cell", "cell", "drop", "add"]))
        if action == "cell" and row:
            row[draw(st.integers(0, len(row) - 1))] = draw(st.one_of(st.sampled_from(_CELLS), st.text(max_size=4)))
        elif action == "drop" and row:
            row.pop()
        else:
            row.append(draw(st.sampled_from(_CELLS)))
    ending = draw(st.sampled_from(["\n", "\n", "\r\n", "\r"]))
    return ending.join([sep.join(header)] + [sep.join(r) for r in rows])


_LAYOUT_ARGS = st.fixed_dictionaries(
    {
        "fs": st.integers(0, 9).flatmap(
            lambda k: st.floats() if k == 9 else st.sampled_from([None, 1.0, None, 1.02, 100.0, 0.0, float("nan")])
        ),
        "layout": st.sampled_from(["auto"] * 6 + ["native", "imucal", "imucal_counts", "other"]),
    },
    optional={"gyro_counts_per_dps": st.sampled_from([16.4, 16.4, 0.0, -1.0, [1, 2, 3], "x"]),
              "accel_counts_per_g": st.sampled_from([2048, 2048, 1e-300, [1, 2]])},
)


def _only_recording_errors(text: str | bytes, kwargs: dict[str, object]) -> None:
    try:
        rec = parse_recording_text(text, source="fuzz.csv", **kwargs)  # type: ignore[arg-type]
    except RecordingError as exc:
        assert str(exc)
    else:
        validate_recording(rec)


@settings(max_examples=300, deadline=None)
@given(csv_texts(), _LAYOUT_ARGS)
def test_structured_garbage_only_raises_recording_error(text: str, kwargs: dict[str, object]) -> None:
    _only_recording_errors(text, kwargs)


@st.composite
def mutated_files(draw: st.DrawFn) -> str:
    """A valid native CSV with a few cells, lines or characters changed."""
    buf = io.StringIO()
    write_native_csv(draw(recordings()), buf)
    lines = buf.getvalue().splitlines()
    for _ in range(draw(st.integers(1, 3))):
        k = draw(st.integers(0, len(lines) - 1))
        action = draw(st.sampled_from(["cell", "swap", "chars", "drop"]))
        if action == "cell":
            cells = lines[k].split(",")
            cells[draw(st.integers(0, len(cells) - 1))] = draw(st.one_of(st.sampled_from(_CELLS), st.text(max_size=6)))
            lines[k] = ",".join(cells)
        elif action == "swap":
            j = draw(st.integers(0, len(lines) - 1))
            lines[k], lines[j] = lines[j], lines[k]
        elif action == "chars":
            i = draw(st.integers(0, len(lines[k])))
            lines[k] = lines[k][:i] + draw(st.text(max_size=3)) + lines[k][i + draw(st.integers(0, 3)) :]
        else:
            del lines[k]
    return "\n".join(lines)


@settings(max_examples=200, deadline=None)
@given(mutated_files(), _LAYOUT_ARGS)
def test_mutated_valid_files_only_raise_recording_error(text: str, kwargs: dict[str, object]) -> None:
    _only_recording_errors(text, kwargs)


@settings(max_examples=150, deadline=None)
@given(st.one_of(st.text(max_size=200), st.text(alphabet="t,gxyz0123456789.-\n e", max_size=200)), _LAYOUT_ARGS)
def test_arbitrary_text_only_raises_recording_error(text: str, kwargs: dict[str, object]) -> None:
    _only_recording_errors(text, kwargs)


@settings(max_examples=100, deadline=None)
@given(st.one_of(st.binary(max_size=200), csv_texts().map(lambda s: s.encode("utf-8"))))
def test_arbitrary_file_bytes_only_raise_recording_error(data: bytes) -> None:
    fd, name = tempfile.mkstemp(suffix=".csv")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        try:
            read_recording(name, fs=100.0)
        except RecordingError as exc:
            assert str(exc)
    finally:
        os.unlink(name)


def test_host_time_channel_round_trips_and_is_checked(tmp_path) -> None:
    """host_t (the host's receive clock) is optional, round-trips, and may not go backwards."""
    import numpy as np
    import pytest

    from calib.errors import RecordingError
    from calib.io.readers import parse_recording_text, write_native_csv
    from calib.recording import Recording

    t = np.arange(50) / 100.0
    rec = Recording(t, np.zeros((50, 3)), host_t=t * 1.01 + 0.03)
    path = tmp_path / "h.csv"
    write_native_csv(rec, path)
    back = parse_recording_text(path.read_text())
    assert path.read_text().splitlines()[0] == "t,gx,gy,gz,host_t"
    assert np.array_equal(back.host_t, rec.host_t)
    lines = path.read_text().splitlines()
    lines[10] = lines[10].rsplit(",", 1)[0] + ",0.0"
    with pytest.raises(RecordingError, match="line 11, column host_t: the host receive time goes backwards"):
        parse_recording_text("\n".join(lines))


def test_time_stamps_of_another_clock_are_put_on_the_sampling_grid() -> None:
    """A fixed-rate sensor logged with a host's time stamps (quantised to 0.1 ms, wandering up to half a sample):
    the uniform grid through them, which is the sampling; a missing sample makes the stamps all there is."""
    from calib.recording import fixed_rate_instants

    rng = np.random.default_rng(3)
    true = 0.25 + np.arange(5000) * 0.0099990  # 100.01 Hz
    stamps = np.round(true + rng.uniform(-0.004, 0.004, true.size), 4)  # 0.1 ms steps, up to 0.45 sample off
    grid = fixed_rate_instants(stamps)
    assert grid is not None and np.abs(grid - true).max() < 1e-4  # within a tenth of a millisecond of the truth
    assert np.ptp(np.diff(grid)) < 1e-12
    assert fixed_rate_instants(np.delete(stamps, 2500)) is None  # one sample lost: not a fixed rate any more
    assert fixed_rate_instants(stamps[:2]) is None


def test_imu_tk_xsens_session_is_read_on_its_sampling_grid(real_data: Path) -> None:
    from calib.io.imu_tk import read_imu_tk

    rec = read_imu_tk(real_data / "imu_tk" / "xsens_gyro.mat", real_data / "imu_tk" / "xsens_acc.mat")
    raw = np.loadtxt(real_data / "imu_tk" / "xsens_gyro.mat", usecols=0)
    step = np.diff(rec.t)
    assert np.ptp(step) < 1e-9 and 1 / step.mean() == pytest.approx(100.01, abs=1e-3) and rec.t[0] == 0
    off = (raw - raw[0]) - rec.t
    assert 0.4e-3 < np.abs(off - off.mean()).max() < 0.6e-3  # the file's times wander half a sample about it


def test_imu_tk_files_read_from_their_text_as_from_their_paths(real_data: Path) -> None:
    from calib.io.imu_tk import parse_imu_tk, read_imu_tk

    folder = real_data / "imu_tk"
    by_path = read_imu_tk(folder / "xsens_gyro.mat", folder / "xsens_acc.mat")
    by_text = parse_imu_tk((folder / "xsens_gyro.mat").read_text(), (folder / "xsens_acc.mat").read_text())
    assert np.array_equal(by_path.t, by_text.t) and np.array_equal(by_path.gyro, by_text.gyro)
    assert by_text.accel is not None and by_path.accel is not None and np.array_equal(by_path.accel, by_text.accel)
    with pytest.raises(RecordingError, match=r"gyroscope file \(gyro\) \(imu_tk's files are whitespace-separated rows 't x y z'"):
        parse_imu_tk("t,gx,gy,gz\n0,1,2,3\n", (folder / "xsens_acc.mat").read_text())
    with pytest.raises(RecordingError, match="sampled at the same instants"):
        parse_imu_tk("0 1 2 3\n0.01 1 2 3\n", (folder / "xsens_acc.mat").read_text())
