"""Hash chains over the append-only tables: tampering is evident even to someone who can write the file.

Each row of ``calibrations``, ``recordings`` and ``audit_log`` carries ``row_hash`` =
SHA-256(``prev_hash`` + newline + the row's canonical JSON), where ``prev_hash`` is the ``row_hash`` of the
row before it in its chain (64 zeros for the first) and the canonical JSON holds every other column
(ids, ``chain_seq``, times in UTC to the microsecond, JSON values with sorted keys, a binary column as
its SHA-256; a column added to the schema later, such as ``identity``, only when it is set). ``chain_heads``
keeps each chain's length and last hash, so rows removed from the end show too. Appending locks the chain's
head row: concurrent writers queue instead of forking the chain. A recording's row is checked against its data too:
the CSV its SHA-256 names, holding as many samples as the row says (a recording written short hashes as well as any).
"""

from __future__ import annotations

import gzip
import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from .tables import CHAINED, Chained, ChainHead, RecordingRow, aware

GENESIS = "0" * 64
_NOT_HASHED = {"prev_hash", "row_hash"}
# columns added after rows were chained: hashed when set, left out when NULL, so older rows keep their hashes
_ADDED_LATER = {"identity"}


def _canonical(value: Any) -> Any:
    if isinstance(value, datetime):
        return aware(value).astimezone(UTC).isoformat(timespec="microseconds")
    if isinstance(value, (bytes, bytearray, memoryview)):
        return "sha256:" + hashlib.sha256(bytes(value)).hexdigest()
    return value


def row_content(row: Chained) -> dict[str, Any]:
    """Every hashed column of a chained row, canonical."""
    cols = row.__table__.columns  # type: ignore[attr-defined]
    return content_of({c.key: getattr(row, c.key) for c in cols})


def content_of(values: Mapping[str, Any]) -> dict[str, Any]:
    """The hashed part of a row given as column -> value, canonical."""
    return {k: _canonical(v) for k, v in values.items() if k not in _NOT_HASHED and not (k in _ADDED_LATER and v is None)}


def row_hash(prev_hash: str, content: dict[str, Any]) -> str:
    text = json.dumps(content, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)
    return hashlib.sha256(prev_hash.encode() + b"\n" + text.encode()).hexdigest()


def _head(s: Session, chain: str) -> ChainHead:
    """The chain's head row, locked until the transaction ends (SELECT ... FOR UPDATE; SQLite locks the whole
    database for a write transaction already)."""
    head = s.execute(select(ChainHead).where(ChainHead.chain == chain).with_for_update()).scalar_one_or_none()
    if head is None:
        raise LookupError(f"the store has no head row for the {chain} chain (created with the schema)")
    return head


def lock(s: Session, *chains: str) -> None:
    """Lock chain heads at the start of a write transaction, always in the same order (recordings,
    calibrations, audit_log), so that two transactions never wait for each other's heads."""
    for name in CHAINED:
        if name in chains:
            _head(s, name)


def append(s: Session, row: Chained) -> Chained:
    """Add a row to its table's chain: gives it its id, place and hashes, and moves the head."""
    chain = row.__tablename__  # type: ignore[attr-defined]
    head = _head(s, chain)
    row.id = head.last_id + 1  # type: ignore[attr-defined]
    row.chain_seq = head.seq + 1
    row.prev_hash = head.hash
    row.row_hash = row_hash(head.hash, row_content(row))
    s.add(row)
    head.seq, head.last_id, head.hash = row.chain_seq, row.id, row.row_hash  # type: ignore[attr-defined]
    s.flush()
    return row


@dataclass(frozen=True)
class BrokenLink:
    """The first place a chain does not hold."""

    chain: str
    seq: int | None
    row_id: int | None
    problem: str

    def to_dict(self) -> dict[str, Any]:
        return {"chain": self.chain, "seq": self.seq, "row_id": self.row_id, "problem": self.problem}


@dataclass(frozen=True)
class ChainReport:
    """What verifying every chain found: rows checked per chain and the first broken link, if any."""

    rows: dict[str, int]
    broken: BrokenLink | None

    @property
    def ok(self) -> bool:
        return self.broken is None

    def to_dict(self) -> dict[str, Any]:
        return {"ok": self.ok, "rows": self.rows, "first_broken_link": None if self.broken is None else self.broken.to_dict()}


def verify_chain(s: Session, chain: str, batch: int = 2000) -> tuple[int, BrokenLink | None]:
    """Walk one chain in order; (rows checked, the first broken link or None)."""
    table = CHAINED[chain]
    prev, expect_seq, n = GENESIS, 1, 0
    last_seq = 0
    while True:
        rows = s.execute(
            select(table).where(table.chain_seq >= expect_seq).order_by(table.chain_seq).limit(batch)
        ).scalars().all()
        for row in rows:
            rid = getattr(row, "id", None)
            if row.chain_seq != expect_seq:
                return n, BrokenLink(chain, expect_seq, None,
                                     f"rows {expect_seq}-{row.chain_seq - 1} of the chain are missing (removed)")
            if row.prev_hash != prev:
                return n, BrokenLink(chain, row.chain_seq, rid,
                                     "the row does not follow the one before it (a row before it was changed or replaced)")
            if row_hash(prev, row_content(row)) != row.row_hash:
                return n, BrokenLink(chain, row.chain_seq, rid, "the row's content does not match its hash (changed after it was written)")
            if isinstance(row, RecordingRow) and (problem := recording_problem(row)) is not None:
                return n, BrokenLink(chain, row.chain_seq, rid, problem)
            prev, expect_seq, n, last_seq = row.row_hash, expect_seq + 1, n + 1, row.chain_seq
        s.expunge_all()  # keep memory flat on long chains
        if len(rows) < batch:
            break
    head = s.execute(select(ChainHead).where(ChainHead.chain == chain)).scalar_one_or_none()
    if head is not None and (head.seq != last_seq or head.hash != prev):
        return n, BrokenLink(chain, last_seq + 1 if head.seq > last_seq else head.seq, None,
                             f"the chain's head records {head.seq} rows, {n} are there (rows removed from the end)")
    if head is None and n:
        return n, BrokenLink(chain, None, None, "the chain's head row is missing")
    return n, None


def csv_samples(csv_bytes: bytes) -> int:
    """The samples a native CSV holds: its lines less the header, blank lines and ``#`` comments."""
    lines = csv_bytes.splitlines()
    return max(0, sum(1 for line in lines if line.strip() and not line.startswith(b"#")) - 1)


def recording_problem(row: RecordingRow) -> str | None:
    """What is wrong with an archived recording that its hash cannot show (it was written so), or None: its data
    must be the CSV its SHA-256 names, holding the samples its row counts."""
    try:
        data = gzip.decompress(row.data)
    except (OSError, EOFError) as exc:
        return f"the recording of session {row.session_id} cannot be decompressed ({exc})"
    if hashlib.sha256(data).hexdigest() != row.sha256:
        return f"the recording of session {row.session_id} does not match its SHA-256"
    held = csv_samples(data)
    if held != row.n_samples:
        return (f"the recording of session {row.session_id} holds {held:,} samples where its row says {row.n_samples:,} "
                "(it was cut short or padded when it was written)")
    return None


def verify_all(s: Session) -> ChainReport:
    """Verify every chain; stops at the first broken link."""
    rows: dict[str, int] = {}
    for chain in CHAINED:
        n, broken = verify_chain(s, chain)
        rows[chain] = n
        if broken is not None:
            return ChainReport(rows, broken)
    return ChainReport(rows, None)
