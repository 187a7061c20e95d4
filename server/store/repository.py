"""The per-device store: every read and write of the service, each one transaction.

Calibrations, archived recordings and the audit log are append-only (the database refuses UPDATE,
DELETE, REPLACE and TRUNCATE on them) and hash-chained (tampering shows in ``verify()``); the current
calibration of a device is its latest accepted one. Sessions (live or uploaded) are kept whatever their
outcome. Accepting or discarding a session is a compare-and-set on its undecided state: of any number of
concurrent decisions exactly one wins, the others get DecisionConflict.
"""

from __future__ import annotations

import csv
import gzip
import io
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from typing import Any, cast

from sqlalchemy import CursorResult, delete, func, select, update
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from calib.result import CalibrationResult

from . import chain
from .engine import engine_for, writer
from .errors import DecisionConflict, NotAcceptable, NotFound, StoreError
from .records import (
    CalibrationRecord,
    SessionEnd,
    calibration_record,
    device_dict,
    iso_utc,
    session_dict,
    sha256_hex,
)
from .schema import migrate
from .tables import (
    AuditRow,
    AuthToken,
    CalibrationRow,
    Device,
    Operator,
    RecordingRow,
    SchemaInfo,
    SessionRow,
    SpooledSamples,
    aware,
    utcnow,
)

ALL_CHAINS = ("recordings", "calibrations", "audit_log")


class Store:
    """All persistent state of the service. Thread-safe; every method is one transaction."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.engine = engine_for(url)
        self._read = sessionmaker(self.engine, expire_on_commit=False)
        self._write = sessionmaker(writer(self.engine), expire_on_commit=False)
        try:
            self.migrate()
        except SQLAlchemyError as exc:
            raise StoreError(f"cannot open the store at {self.display_url}: {exc.__class__.__name__}: "
                             f"{getattr(exc, 'orig', None) or exc}") from exc

    @property
    def display_url(self) -> str:
        return self.engine.url.render_as_string(hide_password=True)

    @property
    def dialect(self) -> str:
        return self.engine.dialect.name

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
        """A write transaction; the heads of the chains it appends to are locked first, in a fixed order."""
        with self._write.begin() as s:
            chain.lock(s, *chains)
            yield s

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

    def record_held(self, device_id: str, calibration_id: int | None, operator: str | None = None,
                    written: bool = False) -> None:
        """What the wearable just reported holding (None: nothing). ``written``: it was read back after a write-back by
        ``operator``, which the audit log keeps (the device row keeps only the latest report)."""
        with self._tx(*(("audit_log",) if written else ())) as s:
            now = utcnow()
            row = s.get(Device, device_id)
            if row is None:
                row = Device(id=device_id, first_seen=now, last_seen=now)
                s.add(row)
            row.held_calibration_id, row.held_reported_at, row.last_seen = calibration_id, now, now
            if written:
                self._audit(s, operator, "device.write_back", device_id, None, {"calibration_id": calibration_id})

    def devices(self) -> list[dict[str, Any]]:
        with self._read() as s:
            return [device_dict(r) for r in s.execute(select(Device).order_by(Device.id)).scalars()]

    def device(self, device_id: str) -> dict[str, Any] | None:
        with self._read() as s:
            row = s.get(Device, device_id)
            return None if row is None else device_dict(row)

    # -- operators and tokens -------------------------------------------------------------------
    def add_operator(self, name: str, secret_hash: str) -> None:
        with self._tx("audit_log") as s:
            existing = s.execute(select(Operator).where(Operator.name == name)).scalar_one_or_none()
            if existing is not None and existing.disabled_at is None:
                raise StoreError(f"operator {name!r} exists already; use `gyrocal operator reset {name}` for a new secret")
            if existing is not None:
                existing.secret_hash = secret_hash
                existing.disabled_at = None
            else:
                s.add(Operator(name=name, secret_hash=secret_hash, created_at=utcnow()))
            self._audit(s, None, "operator.add", detail={"operator": name})

    def _active_operator(self, s: Session, name: str) -> Operator:
        op = s.execute(select(Operator).where(Operator.name == name, Operator.disabled_at.is_(None))).scalar_one_or_none()
        if op is None:
            raise NotFound(f"no operator named {name!r}; add one with `gyrocal operator add {name}`")
        return op

    def reset_operator(self, name: str, secret_hash: str) -> None:
        with self._tx("audit_log") as s:
            op = self._active_operator(s, name)
            op.secret_hash = secret_hash
            self._revoke_tokens(s, op.id)
            self._audit(s, None, "operator.reset", detail={"operator": name})

    def disable_operator(self, name: str) -> None:
        with self._tx("audit_log") as s:
            op = self._active_operator(s, name)
            op.disabled_at = utcnow()
            self._revoke_tokens(s, op.id)
            self._audit(s, None, "operator.remove", detail={"operator": name})

    @staticmethod
    def _revoke_tokens(s: Session, operator_id: int) -> None:
        for tok in s.execute(select(AuthToken).where(AuthToken.operator_id == operator_id, AuthToken.revoked_at.is_(None))).scalars():
            tok.revoked_at = utcnow()

    def operators(self) -> list[dict[str, Any]]:
        with self._read() as s:
            rows = s.execute(select(Operator).order_by(Operator.name)).scalars().all()
            return [{"name": r.name, "created_at": iso_utc(r.created_at), "active": r.disabled_at is None} for r in rows]

    def operator_secret_hash(self, name: str) -> str | None:
        """The stored hash of an active operator's secret, or None."""
        with self._read() as s:
            return s.execute(
                select(Operator.secret_hash).where(Operator.name == name, Operator.disabled_at.is_(None))
            ).scalar_one_or_none()

    def set_operator_pin(self, name: str, pin_hash: str | None, why: str = "operator.pin_set") -> None:
        """Give an active operator a PIN (its hash), or take it away (None); audited as ``why``."""
        with self._tx("audit_log") as s:
            self._active_operator(s, name).pin_hash = pin_hash
            self._audit(s, None, why, detail={"operator": name})

    def operator_pin_hash(self, name: str) -> str | None:
        """The stored hash of an active operator's PIN, or None (no such operator, or no PIN)."""
        with self._read() as s:
            return s.execute(select(Operator.pin_hash).where(Operator.name == name, Operator.disabled_at.is_(None))).scalar_one_or_none()

    def add_token(self, operator: str, token_hash: str, expires_at: datetime, client: str | None = None) -> None:
        with self._tx("audit_log") as s:
            op = self._active_operator(s, operator)
            s.add(AuthToken(token_hash=token_hash, operator_id=op.id, created_at=utcnow(), expires_at=expires_at))
            self._audit(s, operator, "auth.sign_in", detail={"client": client} if client else None)

    def operator_for_token(self, token_hash: str) -> str | None:
        """The name of the operator holding this (unexpired, unrevoked) token, or None."""
        with self._read() as s:
            row = s.execute(
                select(Operator.name, AuthToken.expires_at)
                .join(Operator, Operator.id == AuthToken.operator_id)
                .where(AuthToken.token_hash == token_hash, AuthToken.revoked_at.is_(None), Operator.disabled_at.is_(None))
            ).one_or_none()
        if row is None or aware(row.expires_at) <= utcnow():
            return None
        return str(row.name)

    def revoke_token(self, token_hash: str, operator: str | None) -> None:
        with self._tx("audit_log") as s:
            tok = s.get(AuthToken, token_hash)
            if tok is not None and tok.revoked_at is None:
                tok.revoked_at = utcnow()
                self._audit(s, operator, "auth.sign_out")

    # -- sessions -------------------------------------------------------------------------------
    def create_session(self, session_id: str, device_id: str, kind: str, state: str, method: str, operator: str | None,
                       software_version: str, info: dict[str, Any] | None = None) -> None:
        with self._tx("audit_log") as s:
            s.add(SessionRow(id=session_id, device_id=device_id, kind=kind, state=state, method=method, operator=operator,
                             started_at=utcnow(), software_version=software_version, info=info))
            self._audit(s, operator, "session.start", device_id, session_id, {"kind": kind, "method": method})

    def _apply_end(self, s: Session, row: SessionRow, end: SessionEnd, operator: str | None) -> None:
        row.state = end.state
        row.reason_code = end.reason_code
        row.reason = end.reason
        row.result = None if end.result is None else end.result.to_json()
        row.passed = end.passed
        row.ended_at = end.ended_at
        if end.info:
            row.info = {**(row.info or {}), **end.info}
        self._audit(s, operator, f"session.{end.state}", row.device_id, row.id,
                    {"reason_code": end.reason_code} if end.reason_code else None)

    def finish_session(self, session_id: str, end: SessionEnd, operator: str | None = None) -> None:
        """Record a session's end (done, failed, cancelled): state, result and what it saw. Written once: a
        session whose end is stored already is left as it is."""
        with self._tx("audit_log") as s:
            row = s.get(SessionRow, session_id, with_for_update=True)
            if row is None:
                raise NotFound(f"no session {session_id}")
            if row.ended_at is None:
                self._apply_end(s, row, end, operator)

    def session(self, session_id: str) -> dict[str, Any] | None:
        with self._read() as s:
            row = s.get(SessionRow, session_id)
            return None if row is None else session_dict(row)

    def sessions(self, device_id: str | None = None, limit: int = 100) -> list[dict[str, Any]]:
        with self._read() as s:
            q = select(SessionRow).order_by(SessionRow.started_at.desc()).limit(limit)
            if device_id is not None:
                q = q.where(SessionRow.device_id == device_id)
            return [session_dict(r) for r in s.execute(q).scalars()]

    def fail_unfinished_sessions(self, reason: str) -> int:
        """Mark sessions a previous run left open as failed (the watchdog's last word after a restart), and
        archive the samples they had spooled, so a crash leaves the recording for the audit."""
        with self._tx("recordings", "audit_log") as s:
            rows = s.execute(select(SessionRow).where(SessionRow.ended_at.is_(None)).with_for_update()).scalars().all()
            for row in rows:
                spooled = self._assemble_spool(s, row.id)
                info: dict[str, Any] = {}
                if spooled is not None:
                    data, n = spooled
                    self._archive(s, row.id, data, n)
                    info = {"samples": n, "recovered_from_spool": True}
                self._apply_end(s, row, SessionEnd("failed", "service_restarted", reason, info=info), None)
            return len(rows)

    def _decide(self, s: Session, session_id: str, decision: str, operator: str, now: datetime) -> SessionRow:
        """Compare-and-set: mark an undecided session decided; DecisionConflict if someone else was first."""
        result = s.execute(
            update(SessionRow)
            .where(SessionRow.id == session_id, SessionRow.decision.is_(None))
            .values(decision=decision, decided_at=now, decided_by=operator)
            .execution_options(synchronize_session=False)
        )
        won = cast(CursorResult[Any], result).rowcount  # an UPDATE answers with a cursor's row count
        row = s.get(SessionRow, session_id, populate_existing=True)
        if row is None:
            raise NotFound(f"no session {session_id} in the store")
        if won != 1:
            raise DecisionConflict(session_id, str(row.decision), row.decided_by, None if row.decided_at is None else aware(row.decided_at))
        return row

    def discard_session(self, session_id: str, operator: str, end: SessionEnd | None = None) -> None:
        """Discard a session's result: it stays for audit and never becomes current. Exactly one decision wins."""
        with self._tx("recordings", "audit_log") as s:
            row = self._decide(s, session_id, "discarded", operator, utcnow())
            if row.ended_at is None and end is not None:
                self._apply_end(s, row, end, None)
            self._audit(s, operator, "session.discard", row.device_id, session_id)

    # -- spooled samples of running sessions ----------------------------------------------------
    def spool_samples(self, session_id: str, chunk: int, columns: str, rows_csv: bytes, n_samples: int) -> None:
        """Keep a running session's next samples (CSV rows under ``columns``) durably."""
        with self._tx() as s:
            s.add(SpooledSamples(session_id=session_id, chunk=chunk, columns=columns, n_samples=int(n_samples),
                                 data=gzip.compress(rows_csv, compresslevel=1, mtime=0), created_at=utcnow()))

    def spooled_recording(self, session_id: str) -> tuple[bytes, int] | None:
        """The CSV a running (or crashed) session's spool holds so far, and its number of samples."""
        with self._read() as s:
            return self._assemble_spool(s, session_id)

    @staticmethod
    def _assemble_spool(s: Session, session_id: str) -> tuple[bytes, int] | None:
        chunks = s.execute(select(SpooledSamples).where(SpooledSamples.session_id == session_id)
                           .order_by(SpooledSamples.chunk)).scalars().all()
        if not chunks:
            return None
        headers = [c.columns.split(",") for c in chunks]
        common = [col for col in headers[0] if all(col in h for h in headers)]
        out = io.StringIO()
        out.write(",".join(common) + "\n")
        for c, h in zip(chunks, headers, strict=False):
            text = gzip.decompress(c.data).decode()
            if h == common:
                out.write(text)
                continue
            idx = [h.index(col) for col in common]  # a batch with other columns (the device stopped sending one)
            for rec in csv.reader(io.StringIO(text)):
                out.write(",".join(rec[i] for i in idx) + "\n")
        return out.getvalue().encode(), sum(c.n_samples for c in chunks)

    # -- recordings -----------------------------------------------------------------------------
    def _archive(self, s: Session, session_id: str, csv_bytes: bytes, n_samples: int) -> str:
        row = RecordingRow(session_id=session_id, sha256=sha256_hex(csv_bytes), encoding="csv+gzip", n_samples=int(n_samples),
                           size_bytes=len(csv_bytes), data=gzip.compress(csv_bytes, compresslevel=6, mtime=0), created_at=utcnow())
        chain.append(s, row)
        s.execute(delete(SpooledSamples).where(SpooledSamples.session_id == session_id))
        return row.sha256

    def archive_recording(self, session_id: str, csv_bytes: bytes, n_samples: int) -> str:
        """Store a session's raw recording (native CSV, gzip) once; returns its SHA-256 (of the CSV)."""
        with self._tx("recordings") as s:
            existing = s.execute(select(RecordingRow.sha256).where(RecordingRow.session_id == session_id)).scalar_one_or_none()
            return existing if existing is not None else self._archive(s, session_id, csv_bytes, n_samples)

    def recording(self, session_id: str) -> tuple[bytes, str] | None:
        """The archived CSV of a session and its SHA-256 (checked), or None."""
        with self._read() as s:
            row = s.execute(select(RecordingRow).where(RecordingRow.session_id == session_id)).scalar_one_or_none()
            if row is None:
                return None
            data = gzip.decompress(row.data)
            if sha256_hex(data) != row.sha256:
                raise StoreError(f"the archived recording of session {session_id} does not match its SHA-256")
            return data, row.sha256

    def recording_sha256(self, session_id: str) -> str | None:
        with self._read() as s:
            return s.execute(select(RecordingRow.sha256).where(RecordingRow.session_id == session_id)).scalar_one_or_none()

    # -- calibrations ---------------------------------------------------------------------------
    def accept(
        self,
        session_id: str,
        operator: str,
        result: CalibrationResult | None = None,
        *,
        end: SessionEnd | None = None,
        sensor_model: str | None = None,
        firmware: str | None = None,
        recording_csv: bytes | None = None,
        n_samples: int = 0,
    ) -> CalibrationRecord:
        """Make a finished session's result the device's current calibration: one new row, at most one per session.

        The decision is a compare-and-set: of concurrent accepts and discards exactly one wins and the others
        raise DecisionConflict. When the session's end was not written (a store outage), ``end`` — the session as
        it ended — is written in the same transaction, and the recording archived, so a retried accept completes
        everything or nothing.
        """
        with self._tx(*ALL_CHAINS) as s:
            now = utcnow()
            row = self._decide(s, session_id, "accepted", operator, now)
            if row.ended_at is None:
                if end is None:
                    end = SessionEnd("done", result=result, passed=result is not None)
                self._apply_end(s, row, end, None)
            if row.state != "done" or not row.passed or row.result is None:
                raise NotAcceptable(f"session {session_id} is {row.state}{'' if row.passed else ', outside the tolerances'}: "
                                    "only a finished session within tolerances can become a calibration")
            info = row.info or {}
            sensor_model = sensor_model or info.get("sensor_model")
            firmware = firmware or info.get("firmware")
            if row.kind == "upload" and not sensor_model:
                raise NotAcceptable("this result comes from an uploaded recording that names no sensor: upload it again with "
                                    "?sensor_model=...&firmware=... (or give sensor_model when accepting) so the calibration "
                                    "is tied to the sensor it was measured on")
            digest = s.execute(select(RecordingRow.sha256).where(RecordingRow.session_id == session_id)).scalar_one_or_none()
            if digest is None and recording_csv is not None:
                digest = self._archive(s, session_id, recording_csv, n_samples)
            stored = CalibrationResult.from_dict(row.result)  # the result as the session's end recorded it
            shown = stored.to_json()
            cal = CalibrationRow(
                device_id=row.device_id, session_id=session_id,
                k_x=float(stored.k[0]), k_y=float(stored.k[1]), k_z=float(stored.k[2]),
                b_x=float(stored.b[0]), b_y=float(stored.b[1]), b_z=float(stored.b[2]),
                uncertainty=shown["uncertainty"], quality=shown["quality"], result=row.result,
                method=stored.method or row.method, software_version=row.software_version,
                sensor_model=sensor_model, firmware=firmware, source=row.kind, operator=operator, recording_sha256=digest,
                computed_at=aware(row.ended_at) if row.ended_at else now, accepted_at=now,
            )
            chain.append(s, cal)
            self._audit(s, operator, "calibration.accept", row.device_id, session_id, {"calibration_id": cal.id})
            return calibration_record(cal)

    def current_calibration(self, device_id: str, at: datetime | None = None) -> CalibrationRecord | None:
        """The device's latest accepted calibration; with ``at``, the latest one accepted at or before that time."""
        with self._read() as s:
            q = select(CalibrationRow).where(CalibrationRow.device_id == device_id)
            if at is not None:  # in UTC, as every time is written (SQLite compares the text)
                q = q.where(CalibrationRow.accepted_at <= aware(at).astimezone(UTC))
            row = s.execute(q.order_by(CalibrationRow.accepted_at.desc(), CalibrationRow.id.desc()).limit(1)).scalar_one_or_none()
            return None if row is None else calibration_record(row)

    def calibration(self, calibration_id: int) -> CalibrationRecord | None:
        with self._read() as s:
            row = s.get(CalibrationRow, calibration_id)
            return None if row is None else calibration_record(row)

    def calibrations(self, device_id: str) -> list[CalibrationRecord]:
        """Every accepted calibration of a device, newest first."""
        with self._read() as s:
            rows = s.execute(
                select(CalibrationRow).where(CalibrationRow.device_id == device_id)
                .order_by(CalibrationRow.accepted_at.desc(), CalibrationRow.id.desc())
            ).scalars()
            return [calibration_record(r) for r in rows]

    def calibration_count(self) -> int:
        with self._read() as s:
            return int(s.execute(select(func.count()).select_from(CalibrationRow)).scalar_one())

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

    def audit_log(self, device_id: str | None = None, limit: int = 200) -> list[dict[str, Any]]:
        """The newest audit entries first."""
        with self._read() as s:
            q = select(AuditRow).order_by(AuditRow.chain_seq.desc()).limit(limit)
            if device_id is not None:
                q = q.where(AuditRow.device_id == device_id)
            return [
                {"id": r.id, "at": iso_utc(r.at), "operator": r.operator, "action": r.action, "device_id": r.device_id,
                 "session_id": r.session_id, "detail": r.detail}
                for r in s.execute(q).scalars()
            ]
