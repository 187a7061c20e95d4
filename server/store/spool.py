"""A running session's spooled samples, back to the native CSV a crash leaves to archive.

A chunk is either CSV rows under a CSV header (as every chunk was written before), or, when its ``columns`` begin
with BINARY_SPOOL, little-endian float64 rows of the columns named after the prefix. Chunks may name different
columns (a device that stopped sending one): the recording keeps those every chunk has.
"""

from __future__ import annotations

import csv
import gzip
import io
from collections.abc import Sequence

import numpy as np

BINARY_SPOOL = "f8:"  # the prefix of a binary chunk's columns


def _rows(columns: str, data: bytes) -> tuple[list[str], list[list[str]]]:
    """A chunk's column names and its rows as the native CSV's cells (floats as repr, the counter as an integer)."""
    raw = gzip.decompress(data)
    if not columns.startswith(BINARY_SPOOL):
        return columns.split(","), list(csv.reader(io.StringIO(raw.decode())))
    names = columns[len(BINARY_SPOOL):].split(",")
    values = np.frombuffer(raw, dtype="<f8").reshape(-1, len(names))
    cells = [list(map(str, col.astype(np.int64).tolist())) if name == "seq" else list(map(repr, col.tolist()))
             for name, col in zip(names, values.T, strict=True)]
    return names, [list(row) for row in zip(*cells, strict=True)] if cells else []


def spool_csv(chunks: Sequence[tuple[str, bytes]]) -> bytes:
    """The native CSV of a session's spooled chunks ((columns, gzip data), in order), with the columns all of them
    have."""
    parsed = [_rows(columns, data) for columns, data in chunks]
    common = [c for c in parsed[0][0] if all(c in names for names, _ in parsed)]
    out = io.StringIO()
    out.write(",".join(common) + "\n")
    for names, rows in parsed:
        idx = [names.index(c) for c in common]
        out.writelines(",".join(row[i] for i in idx) + "\n" for row in rows)
    return out.getvalue().encode()
