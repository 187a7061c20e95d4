"""Reading and writing recordings as CSV.

Layouts (chosen from the header when ``layout="auto"``):
- ``native``: ``t,gx,gy,gz[,ax,ay,az][,seq][,temp][,host_t]`` with t in s, gyro in deg/s, accel in g,
  temp in C, host_t the host's receive time in s.
  Column order is free and other columns are ignored. A comment line ``# sample_rate_rel_std: <value>`` above the
  header says the times were placed at an estimated rate with that relative standard error (a wearable that sends
  no time stamps); the scale factors' uncertainty then includes it.
- ``imucal``: ``gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z`` (accelerometer in m/s^2) with an optional sample
  index column (``n_samples``, ``samples``, ``index`` or an unnamed first column). There is no time
  column: ``fs`` must be given and t = index / fs.
- ``imucal_counts``: the same columns in raw sensor counts, as in imucal's annotated sessions, which also
  carry a ``part`` label column and are grouped by label (rows are put back in sample order). Needs the
  sensitivities ``gyro_counts_per_dps`` and ``accel_counts_per_g``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import IO

import numpy as np

from calib.errors import RecordingError, SampleRateUnknownError
from calib.io.section import Section
from calib.io.sections import sections_from_labels
from calib.io.table import NATIVE_HEADER, Table, column_indices, decode_text, has_group, parse_numbers, split_table
from calib.io.validation import Locator, check_finite, check_increasing, check_recording, check_sample_rate, validate_recording
from calib.recording import Recording, RecordingMeta
from calib.units import STANDARD_GRAVITY

__all__ = ["LAYOUTS", "parse_recording_text", "read_recording", "validate_recording", "write_native_csv"]

LAYOUTS = ("auto", "native", "imucal", "imucal_counts")
NATIVE_REQUIRED = ("t", "gx", "gy", "gz")
NATIVE_ACCEL = ("ax", "ay", "az")
IMUCAL_GYRO = ("gyr_x", "gyr_y", "gyr_z")
IMUCAL_ACCEL = ("acc_x", "acc_y", "acc_z")
IMUCAL_HEADER = "[n_samples,]gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z"
INDEX_NAMES = ("n_samples", "samples", "sample", "index", "unnamed: 0")
LABEL_COLUMN = "part"
MAX_COUNTER = 2.0**53  # larger counters cannot be held exactly as floats
RATE_REL_STD = "sample_rate_rel_std"  # the comment line above a native header that carries it

def read_recording(
    path: str | os.PathLike[str],
    fs: float | None = None,
    layout: str = "auto",
    *,
    gyro_counts_per_dps: float | np.ndarray | None = None,
    accel_counts_per_g: float | np.ndarray | None = None,
) -> Recording:
    """Read a recording from a CSV file; raises RecordingError saying what is wrong and how to fix it."""
    p = Path(path)
    data = read_file_bytes(p)
    return parse_recording_text(
        decode_text(data, p.name), fs, layout, source=p.name,
        gyro_counts_per_dps=gyro_counts_per_dps, accel_counts_per_g=accel_counts_per_g,
    )


def parse_recording_text(
    text: str | bytes,
    fs: float | None = None,
    layout: str = "auto",
    source: str | None = None,
    *,
    gyro_counts_per_dps: float | np.ndarray | None = None,
    accel_counts_per_g: float | np.ndarray | None = None,
) -> Recording:
    """Parse CSV text (e.g. an uploaded file) into a validated Recording; ``source`` names it in messages."""
    if isinstance(text, (bytes, bytearray, memoryview)):
        text = decode_text(bytes(text), source)
    if not isinstance(text, str):
        raise RecordingError(f"expected CSV text, got {type(text).__name__}")
    where = f"{source}: " if source else ""
    if layout not in LAYOUTS:
        raise RecordingError(f"unknown layout {layout!r}; use one of {', '.join(LAYOUTS)}")
    if fs is not None:
        fs = check_sample_rate(fs, where)
    table = split_table(text, where)
    counts = gyro_counts_per_dps is not None or accel_counts_per_g is not None
    layout = _resolve_layout(table, layout, counts, where)
    if layout == "native":
        if counts:
            raise RecordingError(
                f"{where}this is a native CSV in deg/s and g; gyro_counts_per_dps and accel_counts_per_g "
                "apply only to raw-count files, leave them out"
            )
        return _read_native(table, fs, source)
    sens = None
    if layout == "imucal_counts":
        sens = _sensitivities(table, gyro_counts_per_dps, accel_counts_per_g, where)
    elif counts:
        raise RecordingError(
            f"{where}layout 'imucal' is in deg/s and m/s^2; pass layout='imucal_counts' for raw counts "
            "or leave out gyro_counts_per_dps and accel_counts_per_g"
        )
    return _read_imucal(table, fs, source, sens)


def write_native_csv(rec: Recording, path_or_file: str | os.PathLike[str] | IO[str]) -> None:
    """Write ``rec`` as native CSV (only the optional columns it has); reading it back gives the same values."""
    names = list(NATIVE_REQUIRED)
    columns = [rec.t, *rec.gyro.T]
    if rec.accel is not None:
        names += NATIVE_ACCEL
        columns += list(rec.accel.T)
    cells = [list(map(repr, np.asarray(c, dtype=float).tolist())) for c in columns]  # repr round-trips exactly
    if rec.seq is not None:
        names.append("seq")
        cells.append(list(map(str, rec.seq.tolist())))
    if rec.temp is not None:
        names.append("temp")
        cells.append(list(map(repr, rec.temp.tolist())))
    if rec.host_t is not None:
        names.append("host_t")
        cells.append(list(map(repr, rec.host_t.tolist())))
    rate = "" if rec.meta.sample_rate_rel_std is None else f"# {RATE_REL_STD}: {float(rec.meta.sample_rate_rel_std)!r}\n"
    text = rate + ",".join(names) + "\n" + "".join(",".join(row) + "\n" for row in zip(*cells, strict=False))
    if hasattr(path_or_file, "write"):
        path_or_file.write(text)
        return
    try:
        with open(path_or_file, "w", encoding="utf-8", newline="\n") as f:
            f.write(text)
    except OSError as exc:
        raise RecordingError(f"cannot write {path_or_file} ({exc.strerror or exc}); check the folder exists and is writable") from None


def _resolve_layout(table: Table, layout: str, counts: bool, where: str) -> str:
    present = set(table.names)
    has_native = all(c in present for c in NATIVE_REQUIRED)
    has_imucal = all(c in present for c in IMUCAL_GYRO)
    if layout == "auto":
        if has_native:
            layout = "native"
        elif has_imucal:
            layout = "imucal_counts" if counts or LABEL_COLUMN in present else "imucal"
        elif any(c in present for c in IMUCAL_GYRO + IMUCAL_ACCEL):
            layout = "imucal"
        else:
            layout = "native"
    required: tuple[str, ...]
    if layout == "native":
        required, expected = NATIVE_REQUIRED, NATIVE_HEADER
    else:
        required, expected = IMUCAL_GYRO, IMUCAL_HEADER
    missing = [c for c in required if c not in present]
    if missing:
        found = ", ".join(table.raw_names) or "(none)"
        raise RecordingError(
            f"{where}missing column{'s' if len(missing) > 1 else ''} {', '.join(missing)}; the header has {found} "
            f"but must be {expected} (other columns are ignored)"
        )
    return layout


def _counter(values: np.ndarray, name: str, where: Locator) -> np.ndarray:
    """A sample counter column as int64; it must hold whole numbers."""
    check_finite(values.reshape(-1, 1), name, where)
    bad = np.flatnonzero((values != np.round(values)) | (np.abs(values) >= MAX_COUNTER))
    if bad.size:
        i = int(bad[0])
        raise RecordingError(
            f"{where.at(i, name)}: {values[i]:g} is not a whole sample number; "
            f"column {where.column(name)} must count samples (0, 1, 2, ...)"
        )
    return values.astype(np.int64)


def _unwrap_counter(seq: np.ndarray) -> np.ndarray:
    """Undo wrap-arounds of an 8-, 16- or 32-bit device counter; other backward steps are left for validation."""
    steps = np.diff(seq)
    back = np.flatnonzero(steps <= 0)
    if back.size == 0 or seq.min() < 0:
        return seq
    for bits in (8, 16, 32):
        modulus = 1 << bits
        wrapped = steps[back] + modulus
        if seq.max() < modulus and np.all((wrapped > 0) & (wrapped <= modulus // 16)):
            offset = np.zeros(seq.size, dtype=np.int64)
            offset[back + 1] = modulus
            return seq + np.cumsum(offset)
    return seq


def _read_native(table: Table, fs: float | None, source: str | None) -> Recording:
    names = list(NATIVE_REQUIRED)
    has_accel = has_group(table, NATIVE_ACCEL)
    if has_accel:
        names += NATIVE_ACCEL
    has_seq = "seq" in table.names
    has_temp = "temp" in table.names
    has_host_t = "host_t" in table.names
    names += ["seq"] * has_seq + ["temp"] * has_temp + ["host_t"] * has_host_t
    cols = column_indices(table, names)
    values = parse_numbers(table, cols)
    header = {name: table.raw_names[c] for name, c in zip(names, cols, strict=False)}
    where = Locator(
        source=source,
        lines=table.line_no,
        columns={
            "t": (header["t"],),
            "gyro": tuple(header[c] for c in NATIVE_REQUIRED[1:]),
            "accel": tuple(header.get(c, c) for c in NATIVE_ACCEL),
            "seq": (header.get("seq", "seq"),),
            "temp": (header.get("temp", "temp"),),
            "host_t": (header.get("host_t", "host_t"),),
        },
    )
    col = {name: values[:, j] for j, name in enumerate(names)}
    seq = _unwrap_counter(_counter(col["seq"], "seq", where)) if has_seq else None
    rec = Recording(
        t=col["t"],
        gyro=values[:, 1:4],
        accel=values[:, 4:7] if has_accel else None,
        seq=seq,
        temp=col["temp"] if has_temp else None,
        meta=RecordingMeta(sample_rate_hz=fs, source=source, sample_rate_rel_std=_rate_rel_std(table)),
        host_t=col["host_t"] if has_host_t else None,
    )
    check_recording(rec, where=where)
    return rec


def _rate_rel_std(table: Table) -> float | None:
    """The ``# sample_rate_rel_std: <value>`` comment's value; None without one, RecordingError for a bad one."""
    for line in table.comments:
        name, sep, value = line.partition(":")
        if sep and name.strip() == RATE_REL_STD:
            try:
                rel = float(value)
            except ValueError:
                rel = float("nan")
            if not (np.isfinite(rel) and 0.0 <= rel < 1.0):
                raise RecordingError(f"{table.where}the comment '# {line}' needs a relative standard error from 0 to 1, "
                                     f"such as '# {RATE_REL_STD}: 2e-05'; correct it or delete the line")
            return rel
    return None


def _sensitivities(table: Table, gyro: object, accel: object, where: str) -> tuple[np.ndarray, np.ndarray | None]:
    has_accel = any(c in table.names for c in IMUCAL_ACCEL)
    if gyro is None or (has_accel and accel is None):
        raise RecordingError(
            f"{where}this file holds raw sensor counts (imucal annotated session); pass the sensitivities "
            "gyro_counts_per_dps and accel_counts_per_g from the sensor's datasheet "
            "(e.g. 16.4 and 2048 for a +-2000 deg/s, +-16 g setting; on the command line --gyro-counts-per-dps 16.4 "
            "--accel-counts-per-g 2048)"
        )
    out: list[np.ndarray | None] = []
    for name, value in (("gyro_counts_per_dps", gyro), ("accel_counts_per_g", accel)):
        if value is None:
            out.append(None)
            continue
        try:
            arr = np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()
        except (TypeError, ValueError):
            arr = np.array([np.nan])
        if arr.shape != (3,) or not np.all(np.isfinite(arr) & (arr > 0)):
            raise RecordingError(f"{name} must be a positive number or three positive numbers (x, y, z); got {value!r}")
        out.append(arr)
    gyro_sens = out[0]
    if gyro_sens is None:  # refused above: a counts file always states its gyro sensitivity
        raise RecordingError(f"{where}give gyro_counts_per_dps")
    return gyro_sens, out[1]


def _read_imucal(
    table: Table, fs: float | None, source: str | None, sens: tuple[np.ndarray, np.ndarray | None] | None
) -> Recording:
    where_text = table.where
    index_name = next((n for n in INDEX_NAMES if n in table.names), None)
    if index_name is None and table.names[0] == "" and len(table.names) > 1:
        index_name = ""
    if fs is None:
        raise SampleRateUnknownError(
            f"{where_text}this imucal-style file has no time column, so the sample rate cannot be determined; "
            "pass it as fs in Hz (e.g. fs=102.4)"
        )
    names = list(IMUCAL_GYRO)
    has_accel = has_group(table, IMUCAL_ACCEL)
    if has_accel:
        names += IMUCAL_ACCEL
    cols = column_indices(table, names)
    if index_name is not None:
        cols.append(column_indices(table, [index_name])[0] if index_name else 0)
    values = parse_numbers(table, cols)
    lines = table.line_no
    header = [table.raw_names[c] or "(unnamed index)" for c in cols]
    columns = {
        "t": (header[-1] if index_name is not None else "(row number)",),
        "gyro": tuple(header[:3]),
        "accel": tuple(header[3:6]) if has_accel else IMUCAL_ACCEL,
    }
    seq = None
    sections: tuple[Section, ...] = ()
    if index_name is not None:
        where = Locator(source, lines, {**columns, "seq": columns["t"]})
        seq = _counter(values[:, -1], "seq", where)
        if LABEL_COLUMN in table.names:  # rows are grouped by section label: restore recording order
            order = np.argsort(seq, kind="stable")
            values, seq, lines = values[order], seq[order], lines[order]
            sections = sections_from_labels(_labels(table)[order])
            where = Locator(source, lines, where.columns)
        check_increasing(seq, "seq", where, what="sample index")
        t = seq / fs
    else:
        t = np.arange(len(values)) / fs
    gyro = values[:, :3]
    accel = values[:, 3:6] if has_accel else None
    where = Locator(source, lines, columns)
    if sens is not None:
        gyro = gyro / sens[0]
        accel = accel / sens[1] if accel is not None else None
    elif accel is not None:
        accel = accel / STANDARD_GRAVITY
    meta = RecordingMeta(sample_rate_hz=fs, source=source, sections=sections)
    rec = Recording(t=t, gyro=gyro, accel=accel, seq=seq, meta=meta)
    check_recording(rec, where=where)
    return rec


def _labels(table: Table) -> np.ndarray:
    """The section label column, one string per data line."""
    c = table.index(LABEL_COLUMN)
    cells = [line.split(table.delimiter) for line in table.lines]
    return np.array([row[c].strip().strip("\"'") if c < len(row) else "" for row in cells])


def read_file_bytes(path: str | os.PathLike[str], what: str = "recording") -> bytes:
    """A file's bytes; RecordingError saying why it cannot be read (a folder, missing, not permitted)."""
    p = Path(path)
    if p.is_dir():
        raise RecordingError(f"{p} is a directory, not a {what}; give the path of a file")
    try:
        return p.read_bytes()
    except FileNotFoundError:
        raise RecordingError(f"{p} does not exist; check the path of the {what}") from None
    except OSError as exc:
        raise RecordingError(f"{p} cannot be read ({exc.strerror or exc}); check the path and its permissions") from None
