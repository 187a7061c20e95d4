"""Creating the store's schema and bringing an older one up to date, with Alembic.

The revisions are in ``server/store/migrations/versions``: 0001 the first store, 0002 hash chains on the
history, 0003 what each wearable holds, 0004 operators' PINs, 0005 identities, 0006 the fleet (gateways,
sightings, leases), 0007 kits. An empty database gets the newest schema at once (``create_all``, stamped with the head);
a store made before gyrocal used Alembic is stamped with the revision its ``schema_info.version`` names, then
upgraded. ``schema_info.version`` keeps following the head's number, so a gyrocal from before Alembic still
refuses a newer store.

Many gateways may start at once on one database: the schema is checked and upgraded under a lock
(PostgreSQL's advisory lock, SQLite's write lock), so the upgrade runs once and the others find it done.
A gyrocal older than the store's revision refuses to start and says so.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

from sqlalchemy import Column, Connection, Engine, MetaData, PrimaryKeyConstraint, String, Table, insert, inspect, select, text, update
from sqlalchemy.exc import ProgrammingError

from . import chain, guards
from .engine import writer
from .errors import StoreError
from .tables import CHAINED, Base, ChainHead, SchemaInfo, utcnow

if TYPE_CHECKING:
    from alembic.config import Config

log = logging.getLogger(__name__)
logging.getLogger("alembic").setLevel(logging.WARNING)  # its step-by-step lines; gyrocal says what was upgraded, once

MIGRATIONS = Path(__file__).parent / "migrations"
SCHEMA_LOCK = 0x67797263616C  # PostgreSQL advisory lock key of schema changes ("gyrcal")

# Alembic's own record of the revision, as Alembic makes it. A store that is new or already at the head is opened
# without loading Alembic and its revisions (most of a start's schema work); only an upgrade or a stamp loads them.
VERSION_TABLE = Table("alembic_version", MetaData(), Column("version_num", String(32), nullable=False),
                      PrimaryKeyConstraint("version_num", name="alembic_version_pkc"))


def revisions() -> list[str]:
    """The revisions this gyrocal knows, oldest first: each file in ``migrations/versions`` is named after its
    revision (``0007_kits.py`` holds revision "0007", whose ``down_revision`` is the one before)."""
    return sorted(p.name[:4] for p in (MIGRATIONS / "versions").glob("[0-9][0-9][0-9][0-9]_*.py"))


def head_revision() -> str:
    """The newest revision this gyrocal knows."""
    return revisions()[-1]


SCHEMA_VERSION = int(head_revision())


def _config(conn: Connection) -> Config:
    from alembic.config import Config

    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    cfg.attributes["connection"] = conn
    return cfg


def _current_revision(conn: Connection, tables: set[str]) -> str | None:
    """The revision the store is at, or None when Alembic never stamped it (a store from before gyrocal used it)."""
    if VERSION_TABLE.name not in tables:
        return None
    return conn.execute(select(VERSION_TABLE.c.version_num)).scalar_one_or_none()


def _create(conn: Connection) -> None:
    Base.metadata.create_all(conn)
    guards.install(conn)
    for name in CHAINED:
        conn.execute(insert(ChainHead).values(chain=name, seq=0, last_id=0, hash=chain.GENESIS))
    conn.execute(insert(SchemaInfo).values(id=1, version=SCHEMA_VERSION, migrated_at=utcnow()))
    VERSION_TABLE.create(conn)
    conn.execute(insert(VERSION_TABLE).values(version_num=head_revision()))


def migrate(engine: Engine, display_url: str) -> int:
    """Create the schema on an empty database, or bring an older one to the head revision; returns its number."""
    try:
        with writer(engine).begin() as conn:
            if conn.dialect.name == "postgresql":
                conn.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": SCHEMA_LOCK})
            tables = set(inspect(conn).get_table_names())
            if "schema_info" not in tables:
                if tables & {"devices", "sessions", "calibrations"}:
                    raise StoreError(f"the database at {display_url} holds tables that are not gyrocal's store; use an empty database")
                _create(conn)
                return SCHEMA_VERSION
            current = _current_revision(conn, tables)
            if current is None:  # made before gyrocal used Alembic
                version = int(conn.execute(select(SchemaInfo.version).where(SchemaInfo.id == 1)).scalar_one())
                if version > SCHEMA_VERSION:
                    raise StoreError(f"the store at {display_url} has schema version {version}, newer than this gyrocal "
                                     f"({SCHEMA_VERSION}); upgrade gyrocal")
                current = f"{version:04d}"
                from alembic import command

                command.stamp(_config(conn), current)
            if current not in revisions():
                raise StoreError(f"the store at {display_url} has schema revision {current}, newer than this gyrocal "
                                 f"(which knows up to {head_revision()}): upgrade gyrocal on this computer, or "
                                 "point it at another store")
            if current != head_revision():
                from alembic import command

                command.upgrade(_config(conn), "head")
                conn.execute(update(SchemaInfo).values(version=SCHEMA_VERSION, migrated_at=utcnow()))
                log.info("the store at %s was upgraded from schema revision %s to %s", display_url, current, head_revision())
            return SCHEMA_VERSION
    except ProgrammingError as exc:
        if "permission denied" in str(exc.orig).lower() or "must be owner" in str(exc.orig).lower():
            raise StoreError(f"the store at {display_url} needs its schema created or upgraded, which this database role may "
                             "not do: run `gyrocal store setup --db <the tables' owner's URL> --service-role <this role>` "
                             "once, then start the service again") from None
        raise
