"""What the store hands out and takes in: an accepted calibration, a session as it ended, and the plain dicts
of sessions and devices the API shows."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, Literal, cast

from pydantic import ConfigDict, Field, field_serializer
from typing_extensions import TypedDict  # on Python 3.11 pydantic reads a TypedDict only from typing_extensions

from calib.apply.identity import SensorIdentity, SensorIdentityJson
from calib.judge.verification import TurnVerification
from calib.quality import Quality
from calib.result import CalibrationResult
from calib.result_schema import CalibrationParameters
from calib.watch.schema import WatchOut

from .tables import CalibrationRow, Device, SessionRow, aware, utcnow


def sha256_hex(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


class CalibrationRecord(CalibrationParameters):
    """One accepted calibration (a row of the append-only history): what the store hands out and the API returns. Its
    parameters are those of the result it was accepted from (``calib.result_schema.CalibrationParameters``)."""

    model_config = ConfigDict(frozen=True)

    id: int
    device_id: str
    session_id: str
    quality: Quality | None
    software_version: str
    sensor_model: str | None
    firmware: str | None
    source: Literal["live", "upload", "import"] = Field(
        description="live: a guided session on the device; upload: an uploaded recording; import: a calibration file made elsewhere")
    operator: str
    recording_sha256: str | None
    computed_at: datetime
    accepted_at: datetime
    identity: SensorIdentity | None = Field(None, description="the sensor, power-up and temperature it was measured at; "
                                            "None for a calibration stored before gyrocal recorded them")

    @field_serializer("computed_at", "accepted_at")
    def _iso(self, value: datetime) -> str:
        return value.isoformat()

    @field_serializer("identity")
    def _identity(self, value: SensorIdentity | None) -> SensorIdentityJson | None:
        return None if value is None else value.to_json()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, times in ISO 8601 with their UTC offset."""
        return self.model_dump(mode="json")


@dataclass(frozen=True)
class SessionEnd:
    """A session as it ended: what is written when it ends, and again by an accept if that write was lost."""

    state: str
    reason_code: str | None = None
    reason: str | None = None
    result: CalibrationResult | None = None
    passed: bool | None = None
    info: dict[str, Any] = field(default_factory=dict)
    ended_at: datetime = field(default_factory=utcnow)


def calibration_record(row: CalibrationRow) -> CalibrationRecord:
    result = row.result or {}
    return CalibrationRecord(
        id=row.id,
        device_id=row.device_id,
        session_id=row.session_id,
        k=[row.k_x, row.k_y, row.k_z],
        b=[row.b_x, row.b_y, row.b_z],
        K=result.get("K"),
        G=result.get("G"),
        K_std=result.get("K_std"),
        G_std=result.get("G_std"),
        uncertainty=row.uncertainty,
        quality=row.quality,
        method=row.method,
        software_version=row.software_version,
        sensor_model=row.sensor_model,
        firmware=row.firmware,
        source=cast(Literal["live", "upload", "import"], row.source or "live"),
        operator=row.operator,
        recording_sha256=row.recording_sha256,
        computed_at=aware(row.computed_at),
        accepted_at=aware(row.accepted_at),
        identity=None if row.identity is None else SensorIdentity.from_json(row.identity),
    )


def iso_utc(dt: datetime | None) -> str | None:
    return None if dt is None else aware(dt).isoformat()


class StoredSession(TypedDict):
    """A session as the store keeps it (times in ISO 8601 UTC)."""

    id: str
    device_id: str
    kind: str  # live | upload | import | verify
    state: str
    reason_code: str | None
    reason: str | None
    method: str
    operator: str | None
    started_at: str | None
    ended_at: str | None
    result: dict[str, Any] | None  # the result's JSON form as computed (ResultDoc or TurnVerification)
    passed: bool | None
    decision: str | None
    decided_at: str | None
    decided_by: str | None
    software_version: str
    info: dict[str, Any] | None  # free-form facts of the run: device info, sample rate, turns, warnings, checks
    gateway: str | None


class StoredKitMember(TypedDict):
    device_id: str
    session_id: str


class StoredKit(TypedDict):
    """A kit session as the store keeps it: its wearables' sessions (each a StoredSession of its own) and, once they
    were calibrated together, how each followed the tray."""

    id: str
    operator: str | None
    gateway: str | None
    started_at: str | None
    members: list[StoredKitMember]
    consistency: dict[str, Any] | None
    departed: list[str]
    refusal: str | None


class StoredVerification(TurnVerification):
    """A verification turn kept with its calibration (a session of kind ``verify``)."""

    session_id: str
    calibration_id: int | None
    device_id: str
    at: str | None = Field(description="when it was measured (ISO 8601, UTC)")
    operator: str | None
    source: Literal["live", "upload"] | None = Field(description="live: turned on the device; upload: a recording")


class StoredWatch(WatchOut):
    """A watch of a calibration on a study recording, kept with it (a session of kind ``watch``)."""

    session_id: str
    calibration_id: int | None
    device_id: str
    at: str | None = Field(description="when it was made (ISO 8601, UTC)")
    operator: str | None
    recording: str | None = Field(None, description="the recording's name, as uploaded")


class AuditEntry(TypedDict):
    """One line of the audit log: who did what, when, on which device."""

    id: int
    at: str | None
    operator: str | None
    action: str
    device_id: str | None
    session_id: str | None
    detail: dict[str, Any] | None  # free-form: what each action records


class StoredOperator(TypedDict):
    name: str
    created_at: str | None
    active: bool


class StoredGateway(TypedDict):
    """A gateway sharing the store, as it last announced itself."""

    name: str
    url: str | None
    version: str | None
    started_at: str | None
    heartbeat_at: str | None


class StoredSighting(TypedDict):
    """A wearable as one gateway last saw it."""

    device_id: str
    gateway: str
    last_seen: str | None
    rssi_dbm: int | None


class StoredPowerUp(TypedDict, total=False):
    """The power-up a device last reported, as stored."""

    boot_count: int | None
    booted_at: str | None  # ISO 8601
    temperature_c: float | None
    read_at: str | None  # when the service read it


class StoredDevice(TypedDict):
    """A device as the store keeps it (times in ISO 8601 UTC)."""

    id: str
    name: str | None
    address: str | None
    transport: str | None
    sensor_model: str | None
    firmware: str | None
    serial: str | None
    held_calibration_id: int | None
    held_reported_at: str | None
    power_up: StoredPowerUp | None  # as the device last reported it
    first_seen: str | None
    last_seen: str | None


def session_dict(row: SessionRow) -> StoredSession:
    return {
        "id": row.id,
        "device_id": row.device_id,
        "kind": row.kind,
        "state": row.state,
        "reason_code": row.reason_code,
        "reason": row.reason,
        "method": row.method,
        "operator": row.operator,
        "started_at": iso_utc(row.started_at),
        "ended_at": iso_utc(row.ended_at),
        "result": row.result,
        "passed": row.passed,
        "decision": row.decision,
        "decided_at": iso_utc(row.decided_at),
        "decided_by": row.decided_by,
        "software_version": row.software_version,
        "info": row.info,
        "gateway": row.gateway,
    }


def device_dict(r: Device) -> StoredDevice:
    return {
        "id": r.id,
        "name": r.name,
        "address": r.address,
        "transport": r.transport,
        "sensor_model": r.sensor_model,
        "firmware": r.firmware,
        "serial": r.serial,
        "held_calibration_id": r.held_calibration_id,
        "held_reported_at": iso_utc(r.held_reported_at),
        "power_up": cast(StoredPowerUp | None, r.power_up),  # the JSON column as the store wrote it
        "first_seen": iso_utc(r.first_seen),
        "last_seen": iso_utc(r.last_seen),
    }
