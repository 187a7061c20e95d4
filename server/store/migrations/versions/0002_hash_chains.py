"""Hash chains on the history (chain_seq, prev_hash, row_hash, chain_heads), one calibration per session,
each calibration's source, guards against REPLACE and TRUNCATE, and the spool of running sessions' samples.

Revision ID: 0002
Revises: 0001
"""

from __future__ import annotations

from alembic import op
from sqlalchemy import inspect, select, text, update
from sqlalchemy.orm import Session

from server.store import chain, guards
from server.store.errors import StoreError
from server.store.tables import CHAINED, Base, ChainHead, SessionRow, SpooledSamples

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    """v1 -> v2: chain the existing history in id order, then guard it again."""
    conn = op.get_bind()
    guards.remove(conn)
    Base.metadata.create_all(conn, tables=[ChainHead.__table__, SpooledSamples.__table__])  # type: ignore[list-item]
    for table in CHAINED:
        for col, kind in (("chain_seq", "INTEGER"), ("prev_hash", "VARCHAR(64)"), ("row_hash", "VARCHAR(64)")):
            conn.execute(text(f"ALTER TABLE {table} ADD COLUMN {col} {kind}"))
    conn.execute(text("ALTER TABLE calibrations ADD COLUMN source VARCHAR(16)"))
    s = Session(bind=conn)
    kinds = {sid: kind for sid, kind in s.execute(select(SessionRow.id, SessionRow.kind))}
    for name, model in CHAINED.items():
        # Core over the columns this version has: a later version's columns are not there yet
        table = model.__table__  # type: ignore[attr-defined]
        present = {c["name"] for c in inspect(conn).get_columns(name)}
        rows = conn.execute(select(*[c for c in table.columns if c.name in present]).order_by(table.c.id)).mappings().all()
        prev = chain.GENESIS
        for i, r in enumerate(rows, start=1):
            values = dict(r)
            if name == "calibrations":
                values["source"] = "upload" if kinds.get(values["session_id"]) == "upload" else "live"
            values.update(chain_seq=i, prev_hash=prev)
            values["row_hash"] = prev = chain.row_hash(prev, chain.content_of(values))
            changed = {k: values[k] for k in ("chain_seq", "prev_hash", "row_hash", "source") if k in values}
            conn.execute(update(table).where(table.c.id == values["id"]).values(**changed))
        last_id = rows[-1]["id"] if rows else 0
        s.add(ChainHead(chain=name, seq=len(rows), last_id=last_id, hash=prev))
    s.flush()
    dup = conn.execute(text("SELECT session_id FROM calibrations GROUP BY session_id HAVING COUNT(*) > 1")).scalars().all()
    if dup:
        raise StoreError(f"the store holds {len(dup)} sessions with more than one calibration (e.g. {dup[0]}), written by an "
                         "older gyrocal under concurrent accepts; gyrocal cannot make them unique without rewriting history. "
                         "Keep this gyrocal version away from that store and ask for support")
    for table in CHAINED:
        conn.execute(text(f"CREATE UNIQUE INDEX ux_{table}_chain_seq ON {table} (chain_seq)"))
    conn.execute(text("CREATE UNIQUE INDEX ux_calibrations_session_id ON calibrations (session_id)"))
    guards.install(conn)
