"""The calibration history: accepting a session's result, importing one made elsewhere, and reading them back."""

from __future__ import annotations

from datetime import UTC, datetime

from sqlalchemy import func, select

from calib.result import CalibrationResult

from . import chain
from .base import ALL_CHAINS
from .errors import NotAcceptable
from .records import CalibrationRecord, SessionEnd, calibration_record
from .sessions import SessionStore
from .tables import CalibrationRow, RecordingRow, aware, utcnow


class CalibrationStore(SessionStore):
    """The calibrations' part of the store (append-only, hash-chained)."""

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
