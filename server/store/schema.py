"""Creating the store's schema and bringing an older one up to date.

Version 1: the first store. Version 2: hash chains on the history (``chain_seq``, ``prev_hash``,
``row_hash``, ``chain_heads``), one calibration per session (unique), each calibration's ``source``,
guards against REPLACE and TRUNCATE, and the spool of running sessions' samples (``session_samples``).
Version 3: what each wearable last reported holding (``devices.held_calibration_id``, ``held_reported_at``).
Version 4: an operator's short PIN for signing in on the tablets the service trusts (``operators.pin_hash``).
Version 5: each calibration's sensor, power-up and temperature (``calibrations.identity``) and each device's last
reported power-up (``devices.power_up``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sqlalchemy import Engine, insert, inspect, select, text, update
from sqlalchemy.exc import ProgrammingError
from sqlalchemy.orm import Session

from . import chain, guards
from .errors import StoreError
from .tables import (
    CHAINED,
    Base,
    ChainHead,
    SchemaInfo,
    SessionRow,
    SpooledSamples,
    utcnow,
)

SCHEMA_VERSION = 5


def _v2(conn: Any) -> None:
    """v1 -> v2: chain the existing history in id order, then guard it again."""
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


def _v3(conn: Any) -> None:
    """v2 -> v3: the calibration each wearable holds (devices is not append-only: no guard changes)."""
    conn.execute(text("ALTER TABLE devices ADD COLUMN held_calibration_id INTEGER"))
    kind = "TIMESTAMP WITH TIME ZONE" if conn.dialect.name == "postgresql" else "DATETIME"
    conn.execute(text(f"ALTER TABLE devices ADD COLUMN held_reported_at {kind}"))


def _v4(conn: Any) -> None:
    """v3 -> v4: operators' PINs (operators is not append-only: no guard changes)."""
    conn.execute(text("ALTER TABLE operators ADD COLUMN pin_hash VARCHAR(512)"))


def _v5(conn: Any) -> None:
    """v4 -> v5: identities (a new column is NULL on the existing rows: no row changes, their hashes stand)."""
    conn.execute(text("ALTER TABLE calibrations ADD COLUMN identity JSON"))
    conn.execute(text("ALTER TABLE devices ADD COLUMN power_up JSON"))


# version -> the step that brings a database from version-1 to version
MIGRATIONS: dict[int, Callable[[Any], None]] = {2: _v2, 3: _v3, 4: _v4, 5: _v5}


def migrate(engine: Engine, display_url: str) -> int:
    """Create the schema on an empty database, or bring an older one to SCHEMA_VERSION; returns the version."""
    try:
        with engine.begin() as conn:
            tables = set(inspect(conn).get_table_names())
            if "schema_info" not in tables:
                if tables & {"devices", "sessions", "calibrations"}:
                    raise StoreError(f"the database at {display_url} holds tables that are not gyrocal's store; use an empty database")
                Base.metadata.create_all(conn)
                guards.install(conn)
                for name in CHAINED:
                    conn.execute(insert(ChainHead).values(chain=name, seq=0, last_id=0, hash=chain.GENESIS))
                conn.execute(insert(SchemaInfo).values(id=1, version=SCHEMA_VERSION, migrated_at=utcnow()))
                return SCHEMA_VERSION
            version = int(conn.execute(select(SchemaInfo.version).where(SchemaInfo.id == 1)).scalar_one())
            if version > SCHEMA_VERSION:
                raise StoreError(f"the store at {display_url} has schema version {version}, newer than this gyrocal "
                                 f"({SCHEMA_VERSION}); upgrade gyrocal")
            for v in range(version + 1, SCHEMA_VERSION + 1):
                MIGRATIONS[v](conn)
                conn.execute(update(SchemaInfo).values(version=v, migrated_at=utcnow()))
            return SCHEMA_VERSION
    except ProgrammingError as exc:
        if "permission denied" in str(exc.orig).lower() or "must be owner" in str(exc.orig).lower():
            raise StoreError(f"the store at {display_url} needs its schema created or upgraded, which this database role may "
                             "not do: run `gyrocal store setup --db <the tables' owner's URL> --service-role <this role>` "
                             "once, then start the service again") from None
        raise
