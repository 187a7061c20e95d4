"""What every part of the store shares: the engine, its transactions, the schema, the chains and the audit log."""

from __future__ import annotations

import shutil
import time
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import datetime
from pathlib import Path
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.exc import OperationalError, SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from . import chain
from .engine import engine_for, writer
from .errors import StoreError, StoreFull, is_disk_full
from .records import AuditEntry, iso_utc
from .schema import migrate
from .tables import AuditRow, SchemaInfo, aware, utcnow

ALL_CHAINS = ("recordings", "calibrations", "audit_log")


class StoreBase:
    """The store's connection: thread-safe; every public method of the store is one transaction."""


    def __init__(self, url: str) -> None:
        self.url = url
        self.full_since: float | None = None  # when a write last failed for a full disk (None: writes succeed)
        self.engine = engine_for(url)
        self._read = sessionmaker(self.engine, expire_on_commit=False)
        self._write = sessionmaker(writer(self.engine), expire_on_commit=False)
        try:
            for wait_s in (0.2, 0.5, 1.0, 2.0, None):
                try:
                    self.migrate()
                    break
                except OperationalError as exc:
                    # SQLite: another process is upgrading the same file and holds its lock; wait for it, then find it done
                    if wait_s is None or self.engine.dialect.name != "sqlite" or "database is locked" not in str(exc):
                        raise
                    time.sleep(wait_s)
        except SQLAlchemyError as exc:
            raise StoreError(f"cannot open the store at {self.display_url}: {exc.__class__.__name__}: "
                             f"{getattr(exc, 'orig', None) or exc}") from exc

    @property
    def display_url(self) -> str:
        return self.engine.url.render_as_string(hide_password=True)

    @property
    def dialect(self) -> str:
        return self.engine.dialect.name

    def _db_now(self, s: Session) -> datetime:
        """The database's time (UTC): what every gateway of a fleet judges leases and heartbeats by, whatever its own
        clock says. A PostgreSQL server's clock; an SQLite file's is this computer's, the only one that can open it."""
        if self.dialect == "postgresql":
            return aware(s.execute(select(func.now())).scalar_one())
        return utcnow()

    def clock_offset_s(self) -> float:
        """How far the database's clock is ahead of this computer's (s; negative: behind), measured at the middle of
        one round trip."""
        with self._read() as s:
            before = utcnow()
            db = self._db_now(s)
            after = utcnow()
        return (db - (before + (after - before) / 2)).total_seconds()

    def free_bytes(self) -> int | None:
        """Free space on the disk holding an SQLite store's file; None for a database elsewhere (PostgreSQL) or in
        memory, whose space this service cannot see."""
        db = self.engine.url.database
        if self.dialect != "sqlite" or not db or db == ":memory:":
            return None
        return shutil.disk_usage(Path(db).resolve().parent).free

    def _insert(self, table: type[Any]) -> Any:
        """An INSERT into ``table`` in this store's dialect, which has ON CONFLICT (an atomic upsert)."""
        return postgresql.insert(table) if self.dialect == "postgresql" else sqlite.insert(table)

    def close(self) -> None:
        self.engine.dispose()

    # -- schema and integrity -------------------------------------------------------------------
    def migrate(self) -> int:
        """Create the schema on an empty database, or bring an older one to SCHEMA_VERSION."""
        return migrate(self.engine, self.display_url)

    def schema_version(self) -> int:
        with self._read() as s:
            return int(s.execute(select(SchemaInfo.version)).scalar_one())

    def verify(self) -> chain.ChainReport:
        """Walk every hash chain (calibrations, recordings, audit log); the first broken link, if any."""
        with self._read() as s:
            return chain.verify_all(s)

    def role_may_rewrite_history(self) -> bool:
        """On PostgreSQL: whether the service's database role owns the tables or is a superuser (and so could
        drop the guards). Always False on SQLite, where whoever can write the file can do anything."""
        if self.dialect != "postgresql":
            return False
        from .guards import role_may_rewrite_history

        with self.engine.connect() as conn:
            return role_may_rewrite_history(conn)

    @contextmanager
    def _tx(self, *chains: str) -> Iterator[Session]:
        """A write transaction; the heads of the chains it appends to are locked first, in a fixed order. A full
        disk raises StoreFull (and is remembered in ``full_since`` until a write succeeds again)."""
        try:
            with self._write.begin() as s:
                chain.lock(s, *chains)
                yield s
        except SQLAlchemyError as exc:
            if is_disk_full(exc):
                if self.full_since is None:
                    self.full_since = time.time()
                raise StoreFull(self.display_url, str(getattr(exc, "orig", None) or exc).splitlines()[0]) from exc
            raise
        self.full_since = None

    # -- audit ----------------------------------------------------------------------------------
    @staticmethod
    def _audit(s: Session, operator: str | None, action: str, device_id: str | None = None, session_id: str | None = None,
               detail: dict[str, Any] | None = None) -> None:
        chain.append(s, AuditRow(at=utcnow(), operator=operator, action=action, device_id=device_id, session_id=session_id,
                                 detail=detail))

    def audit(self, operator: str | None, action: str, device_id: str | None = None, session_id: str | None = None,
              detail: dict[str, Any] | None = None) -> None:
        """Append one line to the audit log."""
        with self._tx("audit_log") as s:
            self._audit(s, operator, action, device_id, session_id, detail)

    def audit_log(self, device_id: str | None = None, limit: int = 200) -> list[AuditEntry]:
        """The newest audit entries first."""
        with self._read() as s:
            q = select(AuditRow).order_by(AuditRow.chain_seq.desc()).limit(limit)
            if device_id is not None:
                q = q.where(AuditRow.device_id == device_id)
            return [
                AuditEntry(id=r.id, at=iso_utc(r.at), operator=r.operator, action=r.action, device_id=r.device_id,
                           session_id=r.session_id, detail=r.detail)
                for r in s.execute(q).scalars()
            ]
