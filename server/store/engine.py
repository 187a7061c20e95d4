"""Engines for the store's database URLs: SQLite (file or memory) and PostgreSQL (psycopg 3).

On SQLite every write transaction starts with ``BEGIN IMMEDIATE``: it takes the database's write lock
before reading anything, so two writers (threads or processes) queue (up to 30 s) instead of both
reading a session as undecided and both writing. Reads start a plain deferred transaction.
"""

from __future__ import annotations

import atexit
import contextlib
import weakref
from pathlib import Path
from typing import Any

from sqlalchemy import create_engine, event
from sqlalchemy.engine import Connection, Engine, make_url
from sqlalchemy.exc import ArgumentError

from .errors import StoreError

WRITE = "gyrocal_write"  # execution option of the write engine
SQLITE_BUSY_TIMEOUT_S = 30


def engine_for(url: str) -> Engine:
    """An Engine for a SQLAlchemy URL; a SQLite file's folder is created when missing."""
    try:
        parsed = make_url(url)
    except ArgumentError as exc:
        raise StoreError(f"--db {url!r} is not a database URL (try sqlite:///path/to/file.sqlite3 or "
                         "postgresql://user@host/db)") from exc
    if parsed.drivername == "postgresql":
        parsed = parsed.set(drivername="postgresql+psycopg")  # psycopg 3 is the driver gyrocal installs
    backend = parsed.get_backend_name()
    if backend not in ("sqlite", "postgresql"):
        raise StoreError(f"--db {parsed.render_as_string(hide_password=True)}: gyrocal's store runs on SQLite or PostgreSQL")
    kwargs: dict[str, Any] = {}
    if backend == "sqlite":
        db = parsed.database
        if db and db != ":memory:":
            Path(db).expanduser().parent.mkdir(parents=True, exist_ok=True)
        else:
            from sqlalchemy.pool import StaticPool

            kwargs["poolclass"] = StaticPool  # one shared in-memory database
        kwargs["connect_args"] = {"check_same_thread": False, "timeout": SQLITE_BUSY_TIMEOUT_S}
    else:
        kwargs["pool_pre_ping"] = True
    try:
        engine = create_engine(parsed, **kwargs)
    except ArgumentError as exc:
        raise StoreError(f"cannot use the database {parsed.render_as_string(hide_password=True)}: {exc}") from exc
    except ImportError as exc:  # the database's driver is not installed
        from calib.extras import install_hint

        raise StoreError(f"cannot use the database {parsed.render_as_string(hide_password=True)}: {install_hint(exc)}") from exc
    if backend == "sqlite":
        _sqlite_transactions(engine)
    _ENGINES.add(engine)
    return engine


_ENGINES: weakref.WeakSet[Engine] = weakref.WeakSet()  # this process's engines not yet collected


@atexit.register
def _close_at_exit() -> None:
    """Close every engine's connections as the process ends, whatever the garbage collector does then (a command
    may end with its store's objects never collected): SQLite folds its write-ahead log into the database file when
    its last connection closes, so once a command has ended the file alone holds what it wrote."""
    for engine in list(_ENGINES):
        with contextlib.suppress(Exception):
            engine.dispose()


def _sqlite_transactions(engine: Engine) -> None:
    @event.listens_for(engine, "connect")
    def _pragmas(dbapi_conn: Any, _record: Any) -> None:
        dbapi_conn.isolation_level = None  # gyrocal emits BEGIN itself (below), not the driver
        cur = dbapi_conn.cursor()
        cur.execute("PRAGMA foreign_keys=ON")
        cur.execute("PRAGMA journal_mode=WAL")
        cur.execute("PRAGMA recursive_triggers=ON")  # REPLACE's implicit delete fires the delete guard
        cur.close()

    @event.listens_for(engine, "begin")
    def _begin(conn: Connection) -> None:
        conn.exec_driver_sql("BEGIN IMMEDIATE" if conn.get_execution_options().get(WRITE) else "BEGIN")


def writer(engine: Engine) -> Engine:
    """The same engine, for write transactions (BEGIN IMMEDIATE on SQLite)."""
    return engine.execution_options(**{WRITE: True})
