"""The calibration history: accepting a session's result, importing one made elsewhere, and reading them back."""

from __future__ import annotations

import uuid
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from calib.apply.correction import Correction
from calib.apply.identity import SensorIdentity
from calib.judge.verification import TurnVerification
from calib.result import CalibrationResult

from . import chain
from .base import ALL_CHAINS
from .errors import NotAcceptable, NotFound
from .records import CalibrationRecord, SessionEnd, StoredVerification, StoredWatch, calibration_record, iso_utc
from .sessions import SessionStore
from .tables import CalibrationRow, RecordingRow, SessionRow, aware, utcnow


@dataclass(frozen=True)
class Acceptance:
    """One session's result to accept, with what ``CalibrationStore.accept`` takes beside it."""

    session_id: str
    result: CalibrationResult | None = None
    end: SessionEnd | None = None
    sensor_model: str | None = None
    firmware: str | None = None
    identity: SensorIdentity | None = None
    recording_csv: bytes | None = None
    n_samples: int = 0


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
        identity: SensorIdentity | None = None,
        recording_csv: bytes | None = None,
        n_samples: int = 0,
    ) -> CalibrationRecord:
        """Make a finished session's result the device's current calibration: one new row, at most one per session.

        The decision is a compare-and-set: of concurrent accepts and discards exactly one wins and the others
        raise DecisionConflict. When the session's end was not written (a store outage), ``end`` — the session as
        it ended — is written in the same transaction, and the recording archived, so a retried accept completes
        everything or nothing. ``identity``: the sensor, power-up and temperature it was measured at (what the session
        recorded fills the fields it leaves unknown).
        """
        with self._tx(*ALL_CHAINS) as s:
            return self._accept_in(s, session_id, operator, result, end=end, sensor_model=sensor_model, firmware=firmware,
                                   identity=identity, recording_csv=recording_csv, n_samples=n_samples)

    def accept_many(self, accepts: list[Acceptance], operator: str) -> list[CalibrationRecord]:
        """Accept several sessions' results in one transaction (a kit's wearables): every one becomes its device's
        calibration, with its own audit entry, or none does (the first refusal or conflict raises and nothing is kept)."""
        with self._tx(*ALL_CHAINS) as s:
            return [self._accept_in(s, a.session_id, operator, a.result, end=a.end, sensor_model=a.sensor_model,
                                    firmware=a.firmware, identity=a.identity, recording_csv=a.recording_csv,
                                    n_samples=a.n_samples) for a in accepts]

    def _accept_in(
        self, s: Session, session_id: str, operator: str, result: CalibrationResult | None, *, end: SessionEnd | None,
        sensor_model: str | None, firmware: str | None, identity: SensorIdentity | None, recording_csv: bytes | None,
        n_samples: int,
    ) -> CalibrationRecord:
        """A session's result made its device's calibration inside the transaction ``s`` (see ``accept``)."""
        now = utcnow()
        row = self._decide(s, session_id, "accepted", operator, now)
        if row.ended_at is None:
            if end is None:
                end = SessionEnd("done", result=result, passed=result is not None)
            self._apply_end(s, row, end, None)
        if row.state != "done" or row.result is None:
            why = f" ({row.reason_code}: {row.reason})" if row.reason else ""
            raise NotAcceptable(f"session {session_id} ended {row.state} in the store{why}: only a finished session "
                                "within tolerances can become a calibration")
        if not row.passed:
            raise NotAcceptable(f"session {session_id} is outside the tolerances: only a finished session within "
                                "tolerances can become a calibration")
        info = row.info or {}
        sensor_model = sensor_model or info.get("sensor_model")
        firmware = firmware or info.get("firmware")
        if row.kind == "upload" and not sensor_model:
            raise NotAcceptable("this result comes from an uploaded recording that names no sensor: upload it again with "
                                "?sensor_model=...&firmware=... (or give sensor_model when accepting) so the calibration "
                                "is tied to the sensor it was measured on")
        known = (identity or SensorIdentity()).completed(SensorIdentity.from_json(info.get("identity")))
        known = replace(known.completed(SensorIdentity(sensor_model=sensor_model, firmware=firmware, serial=info.get("serial"))),
                        device_id=row.device_id)
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
            computed_at=aware(row.ended_at) if row.ended_at else now, accepted_at=now, identity=known.to_json(),
        )
        chain.append(s, cal)
        self._audit(s, operator, "calibration.accept", row.device_id, session_id, {"calibration_id": cal.id})
        return calibration_record(cal)

    def import_calibration(self, device_id: str, correction: Correction, operator: str, software_version: str, *,
                           file_name: str, file_sha256: str) -> CalibrationRecord:
        """Add a calibration made elsewhere (an imucal or gyrocal file) to a device's history, marked ``import``: one
        session of kind ``import`` (done, accepted) and its calibration row. The same file (by SHA-256) is imported
        once per device: again raises NotAcceptable naming the calibration it became."""
        with self._tx("calibrations", "audit_log") as s:
            before = s.execute(select(SessionRow.id, SessionRow.info).where(SessionRow.device_id == device_id,
                                                                            SessionRow.kind == "import")).all()
            for sid, info in before:
                if (info or {}).get("sha256") == file_sha256:
                    cid = s.execute(select(CalibrationRow.id).where(CalibrationRow.session_id == sid)).scalar_one_or_none()
                    raise NotAcceptable(f"this file was imported for {device_id} already, as calibration #{cid}")
            now = utcnow()
            ident = replace(correction.identity or SensorIdentity(), device_id=device_id)
            doc = {**correction.to_json(), "identity": ident.to_json(), "method": "imported"}
            info = {"source": "import", "file": file_name, "sha256": file_sha256, "format": correction.source}
            sid = uuid.uuid4().hex
            s.add(SessionRow(id=sid, device_id=device_id, kind="import", state="done", method="imported", operator=operator,
                             started_at=now, ended_at=now, result=doc, passed=True, decision="accepted", decided_at=now,
                             decided_by=operator, software_version=software_version, info=info))
            s.flush()
            k, b = doc["k"], doc["b"]
            cal = CalibrationRow(
                device_id=device_id, session_id=sid, k_x=k[0], k_y=k[1], k_z=k[2], b_x=b[0], b_y=b[1], b_z=b[2],
                uncertainty=None, quality={"accelerometer": doc["accelerometer"]} if doc["accelerometer"] else {}, result=doc,
                method="imported", software_version=software_version, sensor_model=ident.sensor_model, firmware=ident.firmware,
                source="import", operator=operator, recording_sha256=None, computed_at=now, accepted_at=now, identity=ident.to_json(),
            )
            chain.append(s, cal)
            self._audit(s, operator, "calibration.import", device_id, sid, {"calibration_id": cal.id, **info})
            return calibration_record(cal)

    def _kept_with(self, s: Session, calibration_id: int, kind: str, operator: str, software_version: str,
                   result: dict[str, Any], passed: bool, info: dict[str, Any], recording_csv: bytes | None,
                   n_samples: int) -> tuple[SessionRow, CalibrationRow]:
        """A session of ``kind`` (done, ``passed``) kept with calibration ``calibration_id``: its ``result``, and its
        recording archived when there is one. NotFound when there is no such calibration."""
        cal = s.get(CalibrationRow, calibration_id)
        if cal is None:
            raise NotFound(f"no calibration #{calibration_id}")
        now = utcnow()
        row = SessionRow(id=uuid.uuid4().hex, device_id=cal.device_id, kind=kind, state="done", method=kind, operator=operator,
                         started_at=now, ended_at=now, result=result, passed=passed, software_version=software_version,
                         info={"calibration_id": calibration_id, **info})
        s.add(row)
        s.flush()
        if recording_csv is not None:
            self._archive(s, row.id, recording_csv, n_samples)
        return row, cal

    def add_verification(self, calibration_id: int, operator: str, software_version: str, verification: TurnVerification, *,
                         source: str, recording_csv: bytes | None = None, n_samples: int = 0) -> StoredVerification:
        """Keep a verification turn of an accepted calibration: a session of kind ``verify`` (done; passed when the turn
        confirmed the calibration) holding it, its recording archived, and an audit entry. Returns it as listed."""
        with self._tx(*ALL_CHAINS) as s:
            row, cal = self._kept_with(s, calibration_id, "verify", operator, software_version, verification.to_json(),
                                       verification.confirmed, {"source": source}, recording_csv, n_samples)
            self._audit(s, operator, "calibration.verify", cal.device_id, row.id,
                        {"calibration_id": calibration_id, "calibrated_deg": verification.calibrated_deg,
                         "confirmed": verification.confirmed})
            return _verification(row)

    def verifications(self, device_id: str | None = None, calibration_id: int | None = None) -> list[StoredVerification]:
        """Verification turns, newest first: of a device's calibrations, or of one calibration."""
        with self._read() as s:
            q = select(SessionRow).where(SessionRow.kind == "verify").order_by(SessionRow.started_at.desc())
            if device_id is not None:
                q = q.where(SessionRow.device_id == device_id)
            rows = [_verification(r) for r in s.execute(q).scalars()]
        return [v for v in rows if calibration_id is None or v.calibration_id == calibration_id]

    def add_watch(self, calibration_id: int, operator: str, software_version: str, report: dict[str, Any], *,
                  recording_name: str | None, recording_csv: bytes | None = None, n_samples: int = 0) -> StoredWatch:
        """Keep a watch of an accepted calibration on a study recording: a session of kind ``watch`` (done; passed
        unless a parameter moved) holding its report, the recording archived, and an audit entry."""
        with self._tx(*ALL_CHAINS) as s:
            row, cal = self._kept_with(s, calibration_id, "watch", operator, software_version, report, report["verdict"] != "moved",
                                       {"recording": recording_name}, recording_csv, n_samples)
            self._audit(s, operator, "calibration.watch", cal.device_id, row.id,
                        {"calibration_id": calibration_id, "verdict": report["verdict"],
                         "moved": [p["name"] for p in report["parameters"] if p["verdict"] == "moved"]})
            return _watch(row)

    def watches(self, device_id: str, calibration_id: int | None = None, limit: int | None = None) -> list[StoredWatch]:
        """A device's watches, newest first (of one of its calibrations, with ``calibration_id``)."""
        with self._read() as s:
            q = select(SessionRow).where(SessionRow.kind == "watch", SessionRow.device_id == device_id)
            rows = [r for r in s.execute(q.order_by(SessionRow.started_at.desc())).scalars()
                    if calibration_id is None or (r.info or {}).get("calibration_id") == calibration_id]
            # only the ones asked for are read into reports (the device list asks for the latest of each device's)
            return [_watch(r) for r in (rows if limit is None else rows[:limit])]

    def current_calibration(self, device_id: str, at: datetime | None = None) -> CalibrationRecord | None:
        """The device's latest accepted calibration; with ``at``, the latest one accepted at or before that time."""
        with self._read() as s:
            q = select(CalibrationRow).where(CalibrationRow.device_id == device_id)
            if at is not None:  # in UTC, as every time is written (SQLite compares the text)
                q = q.where(CalibrationRow.accepted_at <= aware(at).astimezone(UTC))
            row = s.execute(q.order_by(CalibrationRow.accepted_at.desc(), CalibrationRow.id.desc()).limit(1)).scalar_one_or_none()
            return None if row is None else calibration_record(row)

    def current_calibrations(self) -> dict[str, CalibrationRecord]:
        """Every device's latest accepted calibration, by device id (one query, for the fleet view)."""
        rank = func.row_number().over(partition_by=CalibrationRow.device_id,
                                      order_by=(CalibrationRow.accepted_at.desc(), CalibrationRow.id.desc())).label("rank")
        ranked = select(CalibrationRow.id, rank).subquery()
        q = select(CalibrationRow).join(ranked, ranked.c.id == CalibrationRow.id).where(ranked.c.rank == 1)
        with self._read() as s:
            return {r.device_id: calibration_record(r) for r in s.execute(q).scalars()}

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


def _verification(row: SessionRow) -> StoredVerification:
    info = row.info or {}
    return StoredVerification.model_validate({**(row.result or {}), "session_id": row.id, "calibration_id": info.get("calibration_id"),
                                              "device_id": row.device_id, "at": iso_utc(row.started_at), "operator": row.operator,
                                              "source": info.get("source")})


def _watch(row: SessionRow) -> StoredWatch:
    info = row.info or {}
    return StoredWatch.model_validate({**(row.result or {}), "session_id": row.id, "calibration_id": info.get("calibration_id"),
                                       "device_id": row.device_id, "at": iso_utc(row.started_at), "operator": row.operator,
                                       "recording": info.get("recording")})
