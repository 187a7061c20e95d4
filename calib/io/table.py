"""A CSV file as a table of text: its decoding, its header and rows, the columns a layout needs, and its numbers
parsed fast (every row at once) or, on a bad cell, slowly enough to name it."""

from __future__ import annotations

import io
import re
import warnings
from dataclasses import dataclass

import numpy as np

from calib.errors import RecordingError

NATIVE_HEADER = "t,gx,gy,gz[,ax,ay,az][,seq][,temp][,host_t]"  # gyrocal's own layout, named in messages

_NUMBER = re.compile(r"\s*[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|nan|inf|infinity)\s*", re.ASCII | re.IGNORECASE)


@dataclass
class Table:
    """The header and the non-blank data lines of a CSV, with their 1-based file line numbers."""

    names: list[str]  # normalised (stripped, unquoted, lower case)
    raw_names: list[str]
    lines: list[str]
    line_no: np.ndarray
    delimiter: str
    where: str
    comments: tuple[str, ...] = ()  # the '#' lines above the header, without the '#'

    def index(self, name: str) -> int:
        return self.names.index(name)


def decode_text(data: bytes, source: str | None) -> str:
    name = source or "the upload"
    if b"\x00" in data:
        raise RecordingError(f"{name} is a binary file, not CSV text; export the recording as CSV")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise RecordingError(
            f"{name} is not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}); "
            "export the recording as a UTF-8 CSV file"
        ) from None


def split_table(text: str, where: str) -> Table:
    if "\x00" in text:
        raise RecordingError(f"{where}the content is binary, not CSV text; export the recording as CSV")
    text = text.removeprefix("\ufeff").replace("\r\n", "\n").replace("\r", "\n")
    raw = text.split("\n")
    header_at = next((i for i, line in enumerate(raw) if line.strip() and not line.lstrip().startswith("#")), None)
    if header_at is None:
        raise RecordingError(f"{where}the file is empty; expected a CSV with a header line such as {NATIVE_HEADER}")
    header = raw[header_at]
    if any(ord(c) < 32 and c != "\t" for c in header):
        raise RecordingError(f"{where}line {header_at + 1} holds control characters; this is not CSV text")
    delimiter = next((d for d in (",", "\t", ";") if d in header), ",")
    raw_names = [h.strip() for h in header.split(delimiter)]
    names = [h.strip("\"'").strip().lower() for h in raw_names]
    if all(_NUMBER.fullmatch(h) for h in names):
        raise RecordingError(
            f"{where}line {header_at + 1} holds numbers, not column names; the first line must be a header "
            f"such as {NATIVE_HEADER} (a header commented out with '#' is not read)"
        )
    numbered = [(i, line) for i, line in enumerate(raw[header_at + 1 :], header_at + 2) if line.strip()]
    if not numbered:
        if not any(n in names for n in ("t", "gx", "gyr_x", "gyro_x")):
            raise RecordingError(f"{where}this is not a recording: one line of text ({header[:40]!r}) and no samples. A "
                                 f"recording is a CSV with a header such as {NATIVE_HEADER} and one row per sample")
        raise RecordingError(f"{where}the file has a header but no data rows; it holds no samples")
    line_no = np.fromiter((i for i, _ in numbered), dtype=np.int64, count=len(numbered))
    lines = [line for _, line in numbered]
    fields = np.fromiter((line.count(delimiter) for line in lines), dtype=np.int64, count=len(lines))
    ragged = np.flatnonzero(fields != len(names) - 1)
    if ragged.size:
        k = int(ragged[0])
        raise RecordingError(
            f"{where}line {line_no[k]} has {fields[k] + 1} field{'s' if fields[k] else ''} but the header has {len(names)} "
            f"({delimiter.join(raw_names)}); every row needs exactly one value per column"
        )
    comments = tuple(line.lstrip()[1:].strip() for line in raw[:header_at] if line.lstrip().startswith("#"))
    return Table(names, raw_names, lines, line_no, delimiter, where, comments)


def column_indices(table: Table, wanted: list[str]) -> list[int]:
    """Header positions of the wanted columns; each must appear once."""
    for name in wanted:
        if table.names.count(name) > 1:
            raise RecordingError(f"{table.where}column {name} appears more than once in the header; keep one")
    return [table.index(name) for name in wanted]


def has_group(table: Table, group: tuple[str, ...]) -> bool:
    """True if all columns of the group are present, False if none; an error if only some are."""
    found = [c for c in group if c in table.names]
    if found and len(found) < len(group):
        missing = [c for c in group if c not in found]
        raise RecordingError(
            f"{table.where}the header has {', '.join(found)} but not {', '.join(missing)}; "
            f"{', '.join(group)} go together: add the missing column(s) or remove the others"
        )
    return bool(found)


def parse_numbers(table: Table, cols: list[int]) -> np.ndarray:
    """The given columns as an (n, len(cols)) float array; on bad content the error names line and column."""
    n = len(table.lines)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            values = np.loadtxt(
                io.StringIO("\n".join(table.lines)), dtype=float, delimiter=table.delimiter,
                usecols=cols, ndmin=2, comments=None, encoding=None,
            )
        if values.shape == (n, len(cols)):
            return values
    except (ValueError, TypeError, IndexError, OverflowError):
        pass
    return _parse_numbers_slowly(table, cols)


def _parse_numbers_slowly(table: Table, cols: list[int]) -> np.ndarray:
    values = np.empty((len(table.lines), len(cols)))
    for k, line in enumerate(table.lines):
        cells = line.split(table.delimiter)
        for j, c in enumerate(cols):
            cell = cells[c]
            if not _NUMBER.fullmatch(cell):
                shown = cell.strip() if len(cell) <= 40 else cell.strip()[:40] + "..."
                what = "is empty" if not cell.strip() else f"holds {shown!r}, which is not a number"
                raise RecordingError(
                    f"{table.where}line {table.line_no[k]}, column {table.raw_names[c]}: the cell {what}; "
                    "use plain decimal numbers with '.' as the decimal point"
                )
            values[k, j] = float(cell)
    return values
