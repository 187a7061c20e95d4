"""The store's tables (SQLAlchemy 2 ORM). Units and meanings are those of docs/service.md.

Calibrations, recordings and the audit log are append-only and hash-chained (server.store.chain):
each of their rows carries its place in its chain (``chain_seq``), the hash of the row before it
(``prev_hash``) and its own (``row_hash``). ``chain_heads`` holds each chain's last link.
"""

from __future__ import annotations

from datetime import UTC, datetime
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
    UniqueConstraint,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

APPEND_ONLY_TABLES = ("calibrations", "recordings", "audit_log")


def utcnow() -> datetime:
    return datetime.now(UTC)


def aware(dt: datetime) -> datetime:
    """A datetime read back from the store, in UTC (SQLite returns naive ones; gyrocal writes only UTC)."""
    return dt if dt.tzinfo is not None else dt.replace(tzinfo=UTC)


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
    # what the wearable last said it holds (write-back): a calibration id, or None with held_reported_at set for none
    held_calibration_id: Mapped[int | None] = mapped_column(Integer)
    held_reported_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    # the power-up it last reported {boot_count, booted_at, temperature_c, read_at}; None: never reported one
    power_up: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    first_seen: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    last_seen: Mapped[datetime] = mapped_column(DateTime(timezone=True))


class Operator(Base):
    __tablename__ = "operators"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    name: Mapped[str] = mapped_column(String(128), unique=True)
    secret_hash: Mapped[str] = mapped_column(String(512))
    pin_hash: Mapped[str | None] = mapped_column(String(512))  # a short PIN for trusted tablets (None: no PIN)
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
    kind: Mapped[str] = mapped_column(String(16))  # live | upload | import
    state: Mapped[str] = mapped_column(String(32))
    reason_code: Mapped[str | None] = mapped_column(String(64))
    reason: Mapped[str | None] = mapped_column(Text)
    method: Mapped[str] = mapped_column(String(32))
    operator: Mapped[str | None] = mapped_column(String(128))
    started_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    ended_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    result: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    passed: Mapped[bool | None] = mapped_column(Boolean)
    gateway: Mapped[str | None] = mapped_column(String(64))  # the gateway that runs it (None: a service on its own)
    decision: Mapped[str | None] = mapped_column(String(16))  # accepted | discarded
    decided_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    decided_by: Mapped[str | None] = mapped_column(String(128))
    software_version: Mapped[str] = mapped_column(String(32))
    info: Mapped[dict[str, Any] | None] = mapped_column(JSON)  # device info, sample rate, source


class KitRow(Base):
    """A kit session: the wearables of one tray calibrated together, each in its own session (``sessions``)."""

    __tablename__ = "kits"
    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    operator: Mapped[str | None] = mapped_column(String(128))
    gateway: Mapped[str | None] = mapped_column(String(64))  # the gateway that runs it (None: a service on its own)
    started_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    members: Mapped[list[Any]] = mapped_column(JSON)  # [{"device_id", "session_id"}], in the kit's order
    # once calibrated together: each wearable's coupling residual and departure (server.live.snapshot_schema.KitConsistency)
    consistency: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    departed: Mapped[list[Any] | None] = mapped_column(JSON)  # the device ids that came apart from the kit
    refusal: Mapped[str | None] = mapped_column(Text)  # why the kit could not be calibrated together


class ChainHead(Base):
    """The last link of one hash chain (one row per append-only table); locked while a row is appended."""

    __tablename__ = "chain_heads"
    chain: Mapped[str] = mapped_column(String(32), primary_key=True)
    seq: Mapped[int] = mapped_column(Integer)  # rows in the chain
    last_id: Mapped[int] = mapped_column(Integer)  # the id of the last row (ids are given out here)
    hash: Mapped[str] = mapped_column(String(64))


class Chained:
    """The columns every hash-chained row carries."""

    chain_seq: Mapped[int] = mapped_column(Integer, unique=True)
    prev_hash: Mapped[str] = mapped_column(String(64))
    row_hash: Mapped[str] = mapped_column(String(64))


class RecordingRow(Chained, Base):
    __tablename__ = "recordings"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    session_id: Mapped[str] = mapped_column(ForeignKey("sessions.id"), unique=True)
    sha256: Mapped[str] = mapped_column(String(64))
    encoding: Mapped[str] = mapped_column(String(32))  # "csv+gzip": gyrocal's native CSV, gzip-compressed
    n_samples: Mapped[int] = mapped_column(Integer)
    size_bytes: Mapped[int] = mapped_column(Integer)  # uncompressed
    data: Mapped[bytes] = mapped_column(LargeBinary)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))


class CalibrationRow(Chained, Base):
    __tablename__ = "calibrations"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    device_id: Mapped[str] = mapped_column(String(128), index=True)
    session_id: Mapped[str] = mapped_column(ForeignKey("sessions.id"), unique=True)  # one calibration per session
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
    source: Mapped[str] = mapped_column(String(16))  # live | upload | import: where the calibration came from
    operator: Mapped[str] = mapped_column(String(128))
    recording_sha256: Mapped[str | None] = mapped_column(String(64))
    computed_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    accepted_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    # the sensor, power-up and temperature it was measured at (calib.apply.identity.SensorIdentity's JSON); None before v5
    identity: Mapped[dict[str, Any] | None] = mapped_column(JSON)


class AuditRow(Chained, Base):
    __tablename__ = "audit_log"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    operator: Mapped[str | None] = mapped_column(String(128))
    action: Mapped[str] = mapped_column(String(64))
    device_id: Mapped[str | None] = mapped_column(String(128), index=True)
    session_id: Mapped[str | None] = mapped_column(String(64))
    detail: Mapped[dict[str, Any] | None] = mapped_column(JSON)


class SpooledSamples(Base):
    """A running session's raw samples, appended as they arrive, so that a crash leaves the recording.

    Removed once the session's recording is archived (at its end, or when a restarted service
    archives what a crashed one left).
    """

    __tablename__ = "session_samples"
    __table_args__ = (UniqueConstraint("session_id", "chunk"),)
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    session_id: Mapped[str] = mapped_column(ForeignKey("sessions.id"), index=True)
    chunk: Mapped[int] = mapped_column(Integer)
    columns: Mapped[str] = mapped_column(String(128))  # the CSV header of the rows in data
    n_samples: Mapped[int] = mapped_column(Integer)
    data: Mapped[bytes] = mapped_column(LargeBinary)  # CSV rows (no header), gzip
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))


CHAINED: dict[str, type[Chained]] = {"recordings": RecordingRow, "calibrations": CalibrationRow, "audit_log": AuditRow}


class GatewayRow(Base):
    """A service that reaches wearables (one per room in a hospital), registered in the shared store."""

    __tablename__ = "gateways"
    name: Mapped[str] = mapped_column(String(64), primary_key=True)
    url: Mapped[str | None] = mapped_column(String(512))  # where its pages and API answer
    version: Mapped[str] = mapped_column(String(32))  # gyrocal's version
    started_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    heartbeat_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))


class SightingRow(Base):
    """A wearable as one gateway last saw it (advertising, or connected)."""

    __tablename__ = "device_sightings"
    device_id: Mapped[str] = mapped_column(String(128), primary_key=True)
    gateway: Mapped[str] = mapped_column(String(64), primary_key=True)
    last_seen: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    rssi_dbm: Mapped[int | None] = mapped_column(Integer)  # signal strength at that gateway, when the radio says


class LeaseRow(Base):
    """Which gateway may run a session (or a verification, or a write) on a wearable, until when."""

    __tablename__ = "device_leases"
    device_id: Mapped[str] = mapped_column(String(128), primary_key=True)
    gateway: Mapped[str] = mapped_column(String(64))
    holder: Mapped[str] = mapped_column(String(64))  # the session or verification id, or "write"
    expires_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), index=True)


