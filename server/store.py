"""The per-device store (SQLAlchemy 2): SQLite by default, PostgreSQL by URL.

Calibrations, archived recordings and the audit log are append-only (the database itself refuses
UPDATE and DELETE on them); the current calibration of a device is its latest accepted one.
Sessions (live or uploaded) are kept whatever their outcome, for audit.
"""

from __future__ import annotations

import gzip
import hashlib
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any

from sqlalchemy import (
    JSON,
    Boolean,
    DateTime,
    Float,
    ForeignKey,
    Integer,
    LargeBinary,
    String,
    Text,
    create_engine,
    event,
    func,
    inspect,
    select,
    text,
)
from sqlalchemy.engine import Engine, make_url
from sqlalchemy.exc import ArgumentError, SQLAlchemyError
from sqlalchemy.orm import DeclarativeBase, Mapped, Session, mapped_column, sessionmaker

SCHEMA_VERSION = 1
APPEND_ONLY_TABLES = ("calibrations", "recordings", "audit_log")


class StoreError(Exception):
    """The store could not be opened or written; the message says why."""


def utcnow() -> datetime:
    return datetime.now(timezone.utc)


def _aware(dt: datetime | None) -> datetime | None:
    # SQLite returns naive datetimes; everything gyrocal writes is UTC.
    if dt is None or dt.tzinfo is not None:
        return dt
    return dt.replace(tzinfo=timezone.utc)


class Base(DeclarativeBase):
    type_annotation_map = {dict[str, Any]: JSON, list[Any]: JSON}


class SchemaInfo(Base):
    __tablename__ = "schema_info"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    version: Mapped[int] = mapped_column(Integer)
    migrated_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))


class Device(Base):
    __tablename__ = "devices"
    id: Mapped[str] = mapped_column(String(128), primary_key=True)
    name: Mapped[str | None] = mapped_column(String(256))
    address: Mapped[str | None] = mapped_column(String(128))
    transport: Mapped[str | None] = mapped_column(String(32))
    sensor_model: Mapped[str | None] = mapped_column(String(128))
    firmware: Mapped[str | None] = mapped_column(String(128))
    serial: Mapped[str | None] = mapped_column(String(128))
    first_seen: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    last_seen: Mapped[datetime] = mapped_column(DateTime(timezone=True))


class Operator(Base):
    __tablename__ = "operators"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    name: Mapped[str] = mapped_column(String(128), unique=True)
    secret_hash: Mapped[str] = mapped_column(String(512))
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    disabled_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))


class AuthToken(Base):
    __tablename__ = "auth_tokens"
    token_hash: Mapped[str] = mapped_column(String(64), primary_key=True)
    operator_id: Mapped[int] = mapped_column(ForeignKey("operators.id"))
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    expires_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    revoked_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))


class SessionRow(Base):
    __tablename__ = "sessions"
    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    device_id: Mapped[str] = mapped_column(String(128), index=True)
    kind: Mapped[str] = mapped_column(String(16))  # live | upload
    state: Mapped[str] = mapped_column(String(32))
    reason_code: Mapped[str | None] = mapped_column(String(64))
    reason: Mapped[str | None] = mapped_column(Text)
    method: Mapped[str] = mapped_column(String(32))
    operator: Mapped[str | None] = mapped_column(String(128))
    started_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    ended_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    result: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    passed: Mapped[bool | None] = mapped_column(Boolean)
    decision: Mapped[str | None] = mapped_column(String(16))  # accepted | discarded
    decided_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    decided_by: Mapped[str | None] = mapped_column(String(128))
    software_version: Mapped[str] = mapped_column(String(32))
    info: Mapped[dict[str, Any] | None] = mapped_column(JSON)  # device info, sample rate, source


class RecordingRow(Base):
    __tablename__ = "recordings"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    session_id: Mapped[str] = mapped_column(ForeignKey("sessions.id"), unique=True)
    sha256: Mapped[str] = mapped_column(String(64))
    encoding: Mapped[str] = mapped_column(String(32))  # "csv+gzip": gyrocal's native CSV, gzip-compressed
    n_samples: Mapped[int] = mapped_column(Integer)
    size_bytes: Mapped[int] = mapped_column(Integer)  # uncompressed
    data: Mapped[bytes] = mapped_column(LargeBinary)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))


class CalibrationRow(Base):
    __tablename__ = "calibrations"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    device_id: Mapped[str] = mapped_column(String(128), index=True)
    session_id: Mapped[str] = mapped_column(ForeignKey("sessions.id"))
    k_x: Mapped[float] = mapped_column(Float)
    k_y: Mapped[float] = mapped_column(Float)
    k_z: Mapped[float] = mapped_column(Float)
    b_x: Mapped[float] = mapped_column(Float)
    b_y: Mapped[float] = mapped_column(Float)
    b_z: Mapped[float] = mapped_column(Float)
    uncertainty: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    quality: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    result: Mapped[dict[str, Any]] = mapped_column(JSON)  # the full result as computed
    method: Mapped[str] = mapped_column(String(32))
    software_version: Mapped[str] = mapped_column(String(32))
    sensor_model: Mapped[str | None] = mapped_column(String(128))
    firmware: Mapped[str | None] = mapped_column(String(128))
    operator: Mapped[str] = mapped_column(String(128))
    recording_sha256: Mapped[str | None] = mapped_column(String(64))
    computed_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    accepted_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))


class AuditRow(Base):
    __tablename__ = "audit_log"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    operator: Mapped[str | None] = mapped_column(String(128))
    action: Mapped[str] = mapped_column(String(64))
    device_id: Mapped[str | None] = mapped_column(String(128), index=True)
    session_id: Mapped[str | None] = mapped_column(String(64))
    detail: Mapped[dict[str, Any] | None] = mapped_column(JSON)


_SQLITE_GUARDS = [
    f"CREATE TRIGGER IF NOT EXISTS {t}_no_{op.lower()} BEFORE {op} ON {t} "
    f"BEGIN SELECT RAISE(ABORT, '{t} is append-only'); END"
    for t in APPEND_ONLY_TABLES
    for op in ("UPDATE", "DELETE")
]
_PG_GUARDS = [
    "CREATE OR REPLACE FUNCTION gyrocal_append_only() RETURNS trigger AS $$ "
    "BEGIN RAISE EXCEPTION '% is append-only', TG_TABLE_NAME; END; $$ LANGUAGE plpgsql",
    *[
        f"CREATE TRIGGER {t}_append_only BEFORE UPDATE OR DELETE ON {t} "
        f"FOR EACH ROW EXECUTE FUNCTION gyrocal_append_only()"
        for t in APPEND_ONLY_TABLES
    ],
]


def _create_v1(conn: Any) -> None:
    Base.metadata.create_all(conn)
    guards = _PG_GUARDS if conn.dialect.name == "postgresql" else _SQLITE_GUARDS if conn.dialect.name == "sqlite" else []
    for stmt in guards:
        conn.execute(text(stmt))


# version -> step that brings a database from version-1 to version. A fresh database gets the
# current metadata at once and is stamped with SCHEMA_VERSION.
MIGRATIONS: dict[int, Any] = {1: _create_v1}


@dataclass(frozen=True)
class CalibrationRecord:
    """One accepted calibration, as the API returns it."""

    id: int
    device_id: str
    session_id: str
    k: list[float]
    b: list[float]
    uncertainty: dict[str, Any] | None
    quality: dict[str, Any] | None
    method: str
    software_version: str
    sensor_model: str | None
    firmware: str | None
    operator: str
    recording_sha256: str | None
    computed_at: datetime
    accepted_at: datetime

    def to_dict(self) -> dict[str, Any]:
        d = dict(self.__dict__)
        d["computed_at"] = self.computed_at.isoformat()
        d["accepted_at"] = self.accepted_at.isoformat()
        return d


def _calibration_record(row: CalibrationRow) -> CalibrationRecord:
    return CalibrationRecord(
        id=row.id,
        device_id=row.device_id,
        session_id=row.session_id,
        k=[row.k_x, row.k_y, row.k_z],
        b=[row.b_x, row.b_y, row.b_z],
        uncertainty=row.uncertainty,
        quality=row.quality,
        method=row.method,
        software_version=row.software_version,
        sensor_model=row.sensor_model,
        firmware=row.firmware,
        operator=row.operator,
        recording_sha256=row.recording_sha256,
        computed_at=_aware(row.computed_at),
        accepted_at=_aware(row.accepted_at),
    )


def _session_dict(row: SessionRow) -> dict[str, Any]:
    return {
        "id": row.id,
        "device_id": row.device_id,
        "kind": row.kind,
        "state": row.state,
        "reason_code": row.reason_code,
        "reason": row.reason,
        "method": row.method,
        "operator": row.operator,
        "started_at": _aware(row.started_at).isoformat(),
        "ended_at": None if row.ended_at is None else _aware(row.ended_at).isoformat(),
        "result": row.result,
        "passed": row.passed,
        "decision": row.decision,
        "decided_at": None if row.decided_at is None else _aware(row.decided_at).isoformat(),
        "decided_by": row.decided_by,
        "software_version": row.software_version,
        "info": row.info,
    }


def engine_for(url: str) -> Engine:
    """An Engine for a SQLAlchemy URL; a SQLite file's folder is created when missing."""
    try:
        parsed = make_url(url)
    except ArgumentError as exc:
        raise StoreError(f"--db {url!r} is not a database URL (try sqlite:///path/to/file.sqlite3 or postgresql://user@host/db)") from exc
    if parsed.drivername == "postgresql":
        parsed = parsed.set(drivername="postgresql+psycopg")  # psycopg 3 is the driver gyrocal installs
    kwargs: dict[str, Any] = {"future": True}
    if parsed.get_backend_name() == "sqlite":
        db = parsed.database
        if db and db != ":memory:":
            from pathlib import Path

            Path(db).expanduser().parent.mkdir(parents=True, exist_ok=True)
        else:
            from sqlalchemy.pool import StaticPool

            kwargs["poolclass"] = StaticPool  # one shared in-memory database
        kwargs["connect_args"] = {"check_same_thread": False, "timeout": 30}
    else:
        kwargs["pool_pre_ping"] = True
    try:
        engine = create_engine(parsed, **kwargs)
    except (ArgumentError, ImportError) as exc:
        raise StoreError(f"cannot use the database {parsed.render_as_string(hide_password=True)}: {exc}") from exc
    if parsed.get_backend_name() == "sqlite":

        @event.listens_for(engine, "connect")
        def _sqlite_pragmas(dbapi_conn: Any, _record: Any) -> None:
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA foreign_keys=ON")
            cur.execute("PRAGMA journal_mode=WAL")
            cur.close()

    return engine


def sha256_hex(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


class Store:
    """All persistent state of the service. Thread-safe; every method is one transaction."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.engine = engine_for(url)
        self._sessions = sessionmaker(self.engine, expire_on_commit=False)
        try:
            self.migrate()
        except SQLAlchemyError as exc:
            raise StoreError(f"cannot open the store at {self.display_url}: {exc.__class__.__name__}: {exc.orig if hasattr(exc, 'orig') else exc}") from exc

    @property
    def display_url(self) -> str:
        return self.engine.url.render_as_string(hide_password=True)

    @property
    def dialect(self) -> str:
        return self.engine.dialect.name

    def close(self) -> None:
        self.engine.dispose()

    # -- schema ---------------------------------------------------------------------------------
    def migrate(self) -> int:
        """Create the schema on an empty database, or bring an older one to SCHEMA_VERSION."""
        with self.engine.begin() as conn:
            tables = set(inspect(conn).get_table_names())
            if "schema_info" not in tables:
                if tables & {"devices", "sessions", "calibrations"}:
                    raise StoreError(f"the database at {self.display_url} holds tables that are not gyrocal's store; use an empty database")
                _create_v1(conn)
                conn.execute(SchemaInfo.__table__.insert().values(id=1, version=SCHEMA_VERSION, migrated_at=utcnow()))
                return SCHEMA_VERSION
            version = conn.execute(select(SchemaInfo.version).where(SchemaInfo.id == 1)).scalar_one()
            if version > SCHEMA_VERSION:
                raise StoreError(
                    f"the store at {self.display_url} has schema version {version}, newer than this gyrocal "
                    f"({SCHEMA_VERSION}); upgrade gyrocal"
                )
            for v in range(version + 1, SCHEMA_VERSION + 1):
                MIGRATIONS[v](conn)
                conn.execute(SchemaInfo.__table__.update().values(version=v, migrated_at=utcnow()))
            return SCHEMA_VERSION

    def schema_version(self) -> int:
        with self._sessions() as s:
            return int(s.execute(select(SchemaInfo.version)).scalar_one())

    def _tx(self) -> Any:
        return self._sessions.begin()

    # -- devices --------------------------------------------------------------------------------
    def upsert_device(self, device_id: str, **info: Any) -> None:
        """Record a device (or what is newly known about it) and when it was last seen."""
        now = utcnow()
        cols = {"name", "address", "transport", "sensor_model", "firmware", "serial"}
        with self._tx() as s:
            row = s.get(Device, device_id)
            if row is None:
                row = Device(id=device_id, first_seen=now, last_seen=now)
                s.add(row)
            for key, value in info.items():
                if key in cols and value is not None:
                    setattr(row, key, str(value))
            row.last_seen = now

    def devices(self) -> list[dict[str, Any]]:
        with self._sessions() as s:
            rows = s.execute(select(Device).order_by(Device.id)).scalars().all()
            return [self._device_dict(r) for r in rows]

    def device(self, device_id: str) -> dict[str, Any] | None:
        with self._sessions() as s:
            row = s.get(Device, device_id)
            return None if row is None else self._device_dict(row)

    @staticmethod
    def _device_dict(r: Device) -> dict[str, Any]:
        return {
            "id": r.id,
            "name": r.name,
            "address": r.address,
            "transport": r.transport,
            "sensor_model": r.sensor_model,
            "firmware": r.firmware,
            "serial": r.serial,
            "first_seen": _aware(r.first_seen).isoformat(),
            "last_seen": _aware(r.last_seen).isoformat(),
        }

    # -- operators and tokens -------------------------------------------------------------------
    def add_operator(self, name: str, secret_hash: str) -> None:
        with self._tx() as s:
            existing = s.execute(select(Operator).where(Operator.name == name)).scalar_one_or_none()
            if existing is not None and existing.disabled_at is None:
                raise StoreError(f"operator {name!r} exists already; use `gyrocal operator reset {name}` for a new secret")
            if existing is not None:
                existing.secret_hash = secret_hash
                existing.disabled_at = None
            else:
                s.add(Operator(name=name, secret_hash=secret_hash, created_at=utcnow()))
            self._audit(s, None, "operator.add", detail={"operator": name})

    def reset_operator(self, name: str, secret_hash: str) -> None:
        with self._tx() as s:
            op = s.execute(select(Operator).where(Operator.name == name, Operator.disabled_at.is_(None))).scalar_one_or_none()
            if op is None:
                raise StoreError(f"no operator named {name!r}; add one with `gyrocal operator add {name}`")
            op.secret_hash = secret_hash
            self._revoke_tokens(s, op.id)
            self._audit(s, None, "operator.reset", detail={"operator": name})

    def disable_operator(self, name: str) -> None:
        with self._tx() as s:
            op = s.execute(select(Operator).where(Operator.name == name, Operator.disabled_at.is_(None))).scalar_one_or_none()
            if op is None:
                raise StoreError(f"no operator named {name!r}")
            op.disabled_at = utcnow()
            self._revoke_tokens(s, op.id)
            self._audit(s, None, "operator.remove", detail={"operator": name})

    @staticmethod
    def _revoke_tokens(s: Session, operator_id: int) -> None:
        for tok in s.execute(select(AuthToken).where(AuthToken.operator_id == operator_id, AuthToken.revoked_at.is_(None))).scalars():
            tok.revoked_at = utcnow()

    def operators(self) -> list[dict[str, Any]]:
        with self._sessions() as s:
            rows = s.execute(select(Operator).order_by(Operator.name)).scalars().all()
            return [
                {
                    "name": r.name,
                    "created_at": _aware(r.created_at).isoformat(),
                    "active": r.disabled_at is None,
                }
                for r in rows
            ]

    def operator_secret_hash(self, name: str) -> str | None:
        """The stored hash of an active operator's secret, or None."""
        with self._sessions() as s:
            return s.execute(
                select(Operator.secret_hash).where(Operator.name == name, Operator.disabled_at.is_(None))
            ).scalar_one_or_none()

    def add_token(self, operator: str, token_hash: str, expires_at: datetime) -> None:
        with self._tx() as s:
            op_id = s.execute(select(Operator.id).where(Operator.name == operator, Operator.disabled_at.is_(None))).scalar_one()
            s.add(AuthToken(token_hash=token_hash, operator_id=op_id, created_at=utcnow(), expires_at=expires_at))
            self._audit(s, operator, "auth.sign_in")

    def operator_for_token(self, token_hash: str) -> str | None:
        """The name of the operator holding this (unexpired, unrevoked) token, or None."""
        with self._sessions() as s:
            row = s.execute(
                select(Operator.name, AuthToken.expires_at)
                .join(Operator, Operator.id == AuthToken.operator_id)
                .where(AuthToken.token_hash == token_hash, AuthToken.revoked_at.is_(None), Operator.disabled_at.is_(None))
            ).one_or_none()
        if row is None or _aware(row.expires_at) <= utcnow():
            return None
        return str(row.name)

    def revoke_token(self, token_hash: str, operator: str | None) -> None:
        with self._tx() as s:
            tok = s.get(AuthToken, token_hash)
            if tok is not None and tok.revoked_at is None:
                tok.revoked_at = utcnow()
                self._audit(s, operator, "auth.sign_out")

    # -- sessions -------------------------------------------------------------------------------
    def create_session(
        self,
        session_id: str,
        device_id: str,
        kind: str,
        state: str,
        method: str,
        operator: str | None,
        software_version: str,
        info: dict[str, Any] | None = None,
    ) -> None:
        with self._tx() as s:
            s.add(
                SessionRow(
                    id=session_id,
                    device_id=device_id,
                    kind=kind,
                    state=state,
                    method=method,
                    operator=operator,
                    started_at=utcnow(),
                    software_version=software_version,
                    info=info,
                )
            )
            self._audit(s, operator, "session.start", device_id, session_id, {"kind": kind, "method": method})

    def finish_session(
        self,
        session_id: str,
        state: str,
        *,
        reason_code: str | None = None,
        reason: str | None = None,
        result: dict[str, Any] | None = None,
        passed: bool | None = None,
        operator: str | None = None,
        info: dict[str, Any] | None = None,
    ) -> None:
        """Record a session's end state (done, failed, cancelled) and its result."""
        with self._tx() as s:
            row = s.get(SessionRow, session_id)
            if row is None:
                raise StoreError(f"no session {session_id}")
            row.state = state
            row.reason_code = reason_code
            row.reason = reason
            row.result = result
            row.passed = passed
            row.ended_at = utcnow()
            if info:
                row.info = {**(row.info or {}), **info}
            self._audit(s, operator, f"session.{state}", row.device_id, session_id, {"reason_code": reason_code} if reason_code else None)

    def session(self, session_id: str) -> dict[str, Any] | None:
        with self._sessions() as s:
            row = s.get(SessionRow, session_id)
            return None if row is None else _session_dict(row)

    def sessions(self, device_id: str | None = None, limit: int = 100) -> list[dict[str, Any]]:
        with self._sessions() as s:
            q = select(SessionRow).order_by(SessionRow.started_at.desc()).limit(limit)
            if device_id is not None:
                q = q.where(SessionRow.device_id == device_id)
            return [_session_dict(r) for r in s.execute(q).scalars()]

    def fail_unfinished_sessions(self, reason: str) -> int:
        """Mark sessions a previous run left open as failed (the watchdog's last word after a restart)."""
        with self._tx() as s:
            rows = s.execute(select(SessionRow).where(SessionRow.ended_at.is_(None))).scalars().all()
            for row in rows:
                row.state = "failed"
                row.reason_code = "service_restarted"
                row.reason = reason
                row.ended_at = utcnow()
                self._audit(s, None, "session.failed", row.device_id, row.id, {"reason_code": "service_restarted"})
            return len(rows)

    def discard_session(self, session_id: str, operator: str) -> None:
        with self._tx() as s:
            row = s.get(SessionRow, session_id)
            if row is None:
                raise StoreError(f"no session {session_id}")
            if row.decision is not None:
                raise StoreError(f"session {session_id} was {row.decision} already")
            row.decision = "discarded"
            row.decided_at = utcnow()
            row.decided_by = operator
            self._audit(s, operator, "session.discard", row.device_id, session_id)

    # -- recordings -----------------------------------------------------------------------------
    @staticmethod
    def _recording_row(session_id: str, csv_bytes: bytes, n_samples: int) -> RecordingRow:
        return RecordingRow(
            session_id=session_id,
            sha256=sha256_hex(csv_bytes),
            encoding="csv+gzip",
            n_samples=int(n_samples),
            size_bytes=len(csv_bytes),
            data=gzip.compress(csv_bytes, compresslevel=6, mtime=0),
            created_at=utcnow(),
        )

    def archive_recording(self, session_id: str, csv_bytes: bytes, n_samples: int) -> str:
        """Store a session's raw recording (native CSV, gzip); returns its SHA-256 (of the CSV)."""
        row = self._recording_row(session_id, csv_bytes, n_samples)
        with self._tx() as s:
            s.add(row)
        return row.sha256

    def recording(self, session_id: str) -> tuple[bytes, str] | None:
        """The archived CSV of a session and its SHA-256 (checked), or None."""
        with self._sessions() as s:
            row = s.execute(select(RecordingRow).where(RecordingRow.session_id == session_id)).scalar_one_or_none()
            if row is None:
                return None
            data = gzip.decompress(row.data)
            if sha256_hex(data) != row.sha256:
                raise StoreError(f"the archived recording of session {session_id} does not match its SHA-256")
            return data, row.sha256

    def recording_sha256(self, session_id: str) -> str | None:
        with self._sessions() as s:
            return s.execute(select(RecordingRow.sha256).where(RecordingRow.session_id == session_id)).scalar_one_or_none()

    # -- calibrations ---------------------------------------------------------------------------
    def accept(
        self,
        session_id: str,
        operator: str,
        result: dict[str, Any],
        *,
        sensor_model: str | None = None,
        firmware: str | None = None,
        recording_csv: bytes | None = None,
        n_samples: int = 0,
    ) -> CalibrationRecord:
        """Make a finished session's result the device's current calibration: one new row.

        The session row is brought up to date and the recording archived in the same transaction
        when an earlier write of them failed, so a retried accept completes everything or nothing.
        """
        with self._tx() as s:
            row = s.get(SessionRow, session_id)
            if row is None:
                raise StoreError(f"no session {session_id} in the store")
            if row.decision is not None:
                raise StoreError(f"session {session_id} was {row.decision} already")
            if row.result is None:
                row.result = result
                row.state = "done"
                row.passed = True
                row.ended_at = row.ended_at or utcnow()
            digest = s.execute(select(RecordingRow.sha256).where(RecordingRow.session_id == session_id)).scalar_one_or_none()
            if digest is None and recording_csv is not None:
                digest = sha256_hex(recording_csv)
                s.add(self._recording_row(session_id, recording_csv, n_samples))
            info = row.info or {}
            now = utcnow()
            cal = CalibrationRow(
                device_id=row.device_id,
                session_id=session_id,
                k_x=float(result["k"][0]),
                k_y=float(result["k"][1]),
                k_z=float(result["k"][2]),
                b_x=float(result["b"][0]),
                b_y=float(result["b"][1]),
                b_z=float(result["b"][2]),
                uncertainty=result.get("uncertainty"),
                quality=result.get("quality"),
                result=result,
                method=str(result.get("method") or row.method),
                software_version=row.software_version,
                sensor_model=sensor_model or info.get("sensor_model"),
                firmware=firmware or info.get("firmware"),
                operator=operator,
                recording_sha256=digest,
                computed_at=_aware(row.ended_at) or now,
                accepted_at=now,
            )
            s.add(cal)
            row.decision = "accepted"
            row.decided_at = now
            row.decided_by = operator
            s.flush()
            self._audit(s, operator, "calibration.accept", row.device_id, session_id, {"calibration_id": cal.id})
            return _calibration_record(cal)

    def current_calibration(self, device_id: str) -> CalibrationRecord | None:
        with self._sessions() as s:
            row = s.execute(
                select(CalibrationRow)
                .where(CalibrationRow.device_id == device_id)
                .order_by(CalibrationRow.accepted_at.desc(), CalibrationRow.id.desc())
                .limit(1)
            ).scalar_one_or_none()
            return None if row is None else _calibration_record(row)

    def calibrations(self, device_id: str) -> list[CalibrationRecord]:
        """Every accepted calibration of a device, newest first."""
        with self._sessions() as s:
            rows = s.execute(
                select(CalibrationRow)
                .where(CalibrationRow.device_id == device_id)
                .order_by(CalibrationRow.accepted_at.desc(), CalibrationRow.id.desc())
            ).scalars()
            return [_calibration_record(r) for r in rows]

    def calibration_count(self) -> int:
        with self._sessions() as s:
            return int(s.execute(select(func.count()).select_from(CalibrationRow)).scalar_one())

    # -- audit ----------------------------------------------------------------------------------
    @staticmethod
    def _audit(
        s: Session,
        operator: str | None,
        action: str,
        device_id: str | None = None,
        session_id: str | None = None,
        detail: dict[str, Any] | None = None,
    ) -> None:
        s.add(AuditRow(at=utcnow(), operator=operator, action=action, device_id=device_id, session_id=session_id, detail=detail))

    def audit(
        self,
        operator: str | None,
        action: str,
        device_id: str | None = None,
        session_id: str | None = None,
        detail: dict[str, Any] | None = None,
    ) -> None:
        """Append one line to the audit log."""
        with self._tx() as s:
            self._audit(s, operator, action, device_id, session_id, detail)

    def audit_log(self, device_id: str | None = None, limit: int = 200) -> list[dict[str, Any]]:
        """The newest audit entries first."""
        with self._sessions() as s:
            q = select(AuditRow).order_by(AuditRow.id.desc()).limit(limit)
            if device_id is not None:
                q = q.where(AuditRow.device_id == device_id)
            return [
                {
                    "id": r.id,
                    "at": _aware(r.at).isoformat(),
                    "operator": r.operator,
                    "action": r.action,
                    "device_id": r.device_id,
                    "session_id": r.session_id,
                    "detail": r.detail,
                }
                for r in s.execute(q).scalars()
            ]

