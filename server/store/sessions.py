"""Sessions as they run and end, the spool of a running session's samples, and archived recordings."""

from __future__ import annotations

import gzip
from datetime import datetime
from typing import Any, cast

from sqlalchemy import CursorResult, delete, select, update
from sqlalchemy.orm import Session

from . import chain
from .base import StoreBase
from .errors import DecisionConflict, NotFound, StoreError
from .records import SessionEnd, StoredSession, session_dict, sha256_hex
from .spool import spool_csv

# gzip's fastest level: a 2 MB recording in 19 ms (level 6: 120 ms, for 8 % less), twenty sessions ending at once
# on a busy service
ARCHIVE_GZIP_LEVEL = 1
from .tables import RecordingRow, SessionRow, SpooledSamples, aware, utcnow


class SessionStore(StoreBase):
    """The sessions' part of the store."""

    # -- sessions -------------------------------------------------------------------------------
    def create_session(self, session_id: str, device_id: str, kind: str, state: str, method: str, operator: str | None,
                       software_version: str, info: dict[str, Any] | None = None, gateway: str | None = None) -> None:
        with self._tx("audit_log") as s:
            s.add(SessionRow(id=session_id, device_id=device_id, kind=kind, state=state, method=method, operator=operator,
                             started_at=utcnow(), software_version=software_version, info=info, gateway=gateway))
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

    def finish_session(self, session_id: str, end: SessionEnd, operator: str | None = None) -> StoredSession | None:
        """Record a session's end (done, failed, cancelled): state, result and what it saw. Written once: a
        session whose end is stored already is left as it is, and returned (None when this end was written)."""
        with self._tx("audit_log") as s:
            row = s.get(SessionRow, session_id, with_for_update=True)
            if row is None:
                raise NotFound(f"no session {session_id}")
            if row.ended_at is None:
                self._apply_end(s, row, end, operator)
                return None
            return session_dict(row)

    def session(self, session_id: str) -> StoredSession | None:
        with self._read() as s:
            row = s.get(SessionRow, session_id)
            return None if row is None else session_dict(row)

    def sessions(self, device_id: str | None = None, limit: int = 100) -> list[StoredSession]:
        with self._read() as s:
            q = select(SessionRow).order_by(SessionRow.started_at.desc()).limit(limit)
            if device_id is not None:
                q = q.where(SessionRow.device_id == device_id)
            return [session_dict(r) for r in s.execute(q).scalars()]

    def fail_unfinished_sessions(self, reason: str, gateway: str | None = None) -> int:
        """Mark sessions a previous run of this service (this ``gateway``; None: a service on its own) left open as
        failed (the watchdog's last word after a restart), and archive the samples they had spooled, so a crash
        leaves the recording for the audit. Other gateways' sessions are theirs: their leases end them."""
        mine = SessionRow.gateway.is_(None) if gateway is None else SessionRow.gateway == gateway
        with self._tx("recordings", "audit_log") as s:
            rows = s.execute(select(SessionRow).where(SessionRow.ended_at.is_(None), mine).with_for_update()).scalars().all()
            for row in rows:
                self._end_with_spool(s, row, "service_restarted", reason)
            return len(rows)

    def _end_with_spool(self, s: Session, row: SessionRow, reason_code: str, reason: str) -> None:
        """End a session its runner can no longer end, as failed, its spooled samples archived."""
        spooled = self._assemble_spool(s, row.id)
        info: dict[str, Any] = {}
        if spooled is not None:
            data, n = spooled
            self._archive(s, row.id, data, n)
            info = {"samples": n, "recovered_from_spool": True}
        self._apply_end(s, row, SessionEnd("failed", reason_code, reason, info=info), None)

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
        """Keep a running session's next samples durably: CSV rows under the CSV header ``columns``, or float64 rows
        under ``BINARY_SPOOL`` + their names (server.store.spool)."""
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
        return spool_csv([(c.columns, c.data) for c in chunks]), sum(c.n_samples for c in chunks)

    # -- recordings -----------------------------------------------------------------------------
    def _archive(self, s: Session, session_id: str, csv_bytes: bytes, n_samples: int) -> str:
        data = gzip.compress(csv_bytes, compresslevel=ARCHIVE_GZIP_LEVEL, mtime=0)
        row = RecordingRow(session_id=session_id, sha256=sha256_hex(csv_bytes), encoding="csv+gzip", n_samples=int(n_samples),
                           size_bytes=len(csv_bytes), data=data, created_at=utcnow())
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
