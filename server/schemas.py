"""The API's request and response bodies (pydantic), as published in the OpenAPI schema."""

from __future__ import annotations

from enum import Enum
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from calib.estimators.registry import method_names
from calib.judge.acceptance import Check
from calib.judge.departure import Departure
from calib.judge.verification import TurnVerification
from calib.result_schema import AccelerometerDoc, ResultDoc

from .lifecycle import CalibrationDue
from .live.codes import EndReason, Phase, State
from .store.records import CalibrationRecord

Method = Enum("Method", {m: m for m in method_names()}, type=str)  # type: ignore[misc]
Method.__doc__ = "An estimator: closure (the default, at the noise floor) or paper (the paper's Algorithm 1)."

Vec3 = list[float]


class Problem(BaseModel):
    """An error: what is wrong and how to fix it."""

    detail: str | list[Any]
    code: str | None = Field(None, description="a recording that could not be read or calibrated: why, in a word (as the "
                                               "command line's error code: bad_recording, bad_sections, turn_missing, ...)")


class BrokenLink(BaseModel):
    chain: str = Field(description="calibrations, recordings or audit_log")
    seq: int | None = Field(description="the row's place in its chain (1 = first)")
    row_id: int | None
    problem: str


class Integrity(BaseModel):
    """The last verification of the hash chains over the store's history."""

    ok: bool
    rows: dict[str, int] = Field(description="rows verified per chain")
    first_broken_link: BrokenLink | None
    checked_at: str


class ClockOut(BaseModel):
    offset_s: float | None = Field(description="the store's database clock minus this service's (s; positive: this "
                                               "computer's clock is behind); None before the first measurement")
    ok: bool = Field(description="whether the offset is within the tolerance (server.clock.MAX_CLOCK_OFFSET_S)")
    measured_at: str | None
    warning: str | None = Field(description="what is wrong and what to do, when not ok")


class Health(BaseModel):
    status: Literal["ok", "degraded", "tampered"] = Field(
        description="tampered: a hash chain of the store's history is broken; degraded: the store cannot take new "
                    "calibrations now (its disk full, finished sessions waiting to be written; `warnings` says which)")
    integrity: Integrity
    version: str
    store: str = Field(description="database dialect of the store (sqlite, postgresql)")
    schema_version: int
    devices: int
    active_sessions: int
    auth_reads: bool = Field(description="whether reads need a token too")
    clock: ClockOut
    store_free_bytes: int | None = Field(description="free space on the disk holding an SQLite store (None: a database "
                                                      "elsewhere, whose space this service cannot see)")
    warnings: list[str] = Field(description="what an operator should act on now, in words (the store's disk full, a "
                                            "clock far off the store's)")


class LoginIn(BaseModel):
    operator: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9][A-Za-z0-9._@-]{0,63}$",
                          description="letters, digits and . _ @ -")
    secret: str | None = Field(None, min_length=1, max_length=512, description="the operator's secret; or give pin")
    pin: str | None = Field(None, pattern=r"^[0-9]{4,8}$", description="the operator's PIN (4-8 digits), from a trusted tablet")

    @model_validator(mode="after")
    def _one_credential(self) -> LoginIn:
        if (self.secret is None) == (self.pin is None):
            raise ValueError("give either secret or pin")
        return self


class PinIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    pin: str = Field(pattern=r"^[0-9]{4,8}$", description="4 to 8 digits")


class LoginOut(BaseModel):
    token: str
    token_type: Literal["bearer"] = "bearer"
    operator: str
    expires_at: str


class Me(BaseModel):
    operator: str


class Truth(BaseModel):
    k: Vec3
    b: Vec3


class PowerUpOut(BaseModel):
    boot_count: int | None = Field(None, description="its count of power-ups (null: it keeps none)")
    booted_at: str | None = Field(None, description="when it was switched on (ISO 8601, to the second)")
    temperature_c: float | None = Field(None, description="its IMU's temperature then, degC (null: no sensor)")
    read_at: str | None = Field(None, description="when the service read it")


class DeviceOut(BaseModel):
    id: str
    name: str | None = None
    transport: str | None = Field(None, description="inprocess (simulated), ble, or null for a device known only from uploads")
    address: str | None = None
    connected: bool = False
    available: bool = Field(False, description="a live session can be started on it")
    simulated: bool = False
    scenario: str | None = None
    sensor_model: str | None = None
    firmware: str | None = None
    serial: str | None = None
    battery_pct: int | None = Field(None, description="battery level, %, when the service has read it (null: not read yet)")
    model: str | None = Field(None, description="the protocol gyrocal speaks with it: gyrocal, polar-pmd, metawear or thingy52 "
                                                "(null: not known yet)")
    model_label: str | None = None
    sample_rate_hz: float | None = Field(None, description="the rate it streams at, Hz (read once connected, else the model's)")
    gyro_full_scale_dps: int | None = Field(None, description="its gyro range, deg/s (read once connected, else the model's)")
    time_stamps: Literal["device", "arrival"] | None = Field(None, description="device: the device's clock; arrival: the "
                                                                               "times samples reached the service")
    loss_detection: Literal["counter", "time_stamps", "none"] | None = None
    limitations: list[str] = Field(default_factory=list, description="what this device's protocol cannot tell")
    write_back: bool = Field(False, description="it can hold a calibration written to it (POST /devices/{id}/calibration/write)")
    held_calibration_id: int | None = Field(None, description="the calibration the device last said it holds")
    held_reported_at: str | None = Field(None, description="when it last said so (null: never asked)")
    held_state: Literal["current", "other", "none"] | None = Field(
        None, description="current: it holds the current calibration; other: it holds another one (write the current one "
                          "to it); none: it holds none; null: not known")
    active_session: str | None = None
    current_calibration: CalibrationRecord | None = None
    calibration_due: CalibrationDue | None = Field(None, description="whether the device should be calibrated again before "
                                                   "a study: never calibrated, switched on again since its calibration, or "
                                                   "its calibration older than the limit")
    power_up: PowerUpOut | None = Field(None, description="the power-up the device last reported (null: it reports none, or "
                                        "has not been connected)")
    last_seen: str | None = None


class DeviceDetail(DeviceOut):
    simulated_truth: Truth | None = Field(None, description="the simulated sensor's true parameters (simulated devices only)")
    info: dict[str, Any] = Field(default_factory=dict)
    recent_sessions: list[dict[str, Any]] = Field(default_factory=list)


class ScanOut(BaseModel):
    devices: list[DeviceOut]


class SessionStart(BaseModel):
    """Options of a guided live session (all optional)."""

    model_config = ConfigDict(extra="forbid")
    method: Method | None = Field(None, description="estimator: closure (default) or paper")
    max_attempts: int | None = Field(None, ge=1, le=5, strict=True, description="tries per turn before the session fails (default 3)")


class SessionStarted(BaseModel):
    session_id: str
    device_id: str
    state: State
    url: str
    events: str


class TurnAccuracy(BaseModel):
    """How well a full turn measures, the worst of the session's turns, before and after the calibration."""

    before_deg: float = Field(description="how far the raw readings (bias removed) of a full turn were from 360°")
    after_deg: float = Field(description="how far from where it began a turn ends, measured with the calibration")


CHECKS_TEXT = ("each tolerance check: name, axis, value, limit, ok, text, used (the share of the allowance the value "
               "uses: 0 ideal, 1 at the limit) and near_limit (passed with used >= 0.8)")


DEPARTURES_TEXT = ("the result's parameters that the device's own earlier calibrations (two at least) do not explain: "
                   "name, axis, value, history_mean, history_spread, z, n_history, text (a dropped or damaged sensor)")


class SessionOut(BaseModel):
    """A full snapshot of a session: what every SSE event carries too."""

    model_config = ConfigDict(extra="allow")
    session_id: str
    device_id: str
    kind: Literal["live", "upload", "import", "verify"] = "live"
    state: State = Field(description="where the session is (protocol order, then reconnecting, computing and the end states)")
    phase: Phase | None = None
    prompt: str | None = None
    reason_code: EndReason | None = Field(None, description="why the session ended, if not done")
    reason: str | None = None
    result: ResultDoc | TurnVerification | None = Field(None, description="the estimator's result (its form numbered by "
                                                       "format_version); a verification session's turn")
    passed: bool | None = None
    checks: list[Check] = Field(default_factory=list, description=CHECKS_TEXT)
    accuracy: TurnAccuracy | None = Field(None, description="a full turn before and after the calibration (closure estimator)")
    departures: list[Departure] = Field(default_factory=list, description=DEPARTURES_TEXT)
    decision: Literal["accepted", "discarded"] | None = None
    calibration_id: int | None = None
    started_at: str | None = None
    ended_at: str | None = None
    stored: bool | None = Field(None, description="a live session that ended: whether the store has its outcome and "
                                                  "recording yet (false: kept by the service and written when it can)")
    store_error: str | None = Field(None, description="why the store could not take them yet (its disk full, ...)")


SENSOR_TEXT = r"^[^\x00-\x1f\x7f]*$"  # printable text: no NUL or other control characters


class DecisionIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    note: str | None = Field(None, max_length=1000, pattern=r"^[^\x00]*$")
    sensor_model: str | None = Field(None, min_length=1, max_length=128, pattern=SENSOR_TEXT,
                                     description="the sensor an uploaded recording came from (accept only; kept with the calibration)")
    firmware: str | None = Field(None, min_length=1, max_length=128, pattern=SENSOR_TEXT)


class WriteBackIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    calibration_id: int | None = Field(None, ge=1, le=0xFFFFFFFF, description="one of the device's calibrations; "
                                                                               "default: its current one")


class HeldOut(BaseModel):
    calibration_id: int
    K: list[list[float]] = Field(description="K of g = K m + b as the device holds it (float32), row by row")
    b: Vec3 = Field(description="b in deg/s of true rate, as the device holds it (float32)")


class WriteBackOut(BaseModel):
    device_id: str
    calibration_id: int
    verified: bool = Field(description="the device read back exactly what was written (float32, CRC-32)")
    held: HeldOut
    held_state: Literal["current", "other"]
    warnings: list[str] = Field(default_factory=list, description="the calibration is of another power-up or temperature")


class AcceptOut(BaseModel):
    session_id: str
    calibration: CalibrationRecord


class OfflineResult(ResultDoc):
    """An uploaded recording's calibration: the estimator's result (its fields as in a session's ``result``), judged
    against the tolerances."""

    session_id: str
    device_id: str
    state: Literal["done", "failed"]
    protocol: str = Field(description="the protocol the recording was calibrated as")
    accelerometer: AccelerometerDoc | None = Field(None, description="as quality.accelerometer")
    passed: bool
    checks: list[Check] = Field(description=CHECKS_TEXT)
    accuracy: TurnAccuracy | None = None
    departures: list[Departure] = Field(default_factory=list, description="as a session's departures")
    reason: str | None = None
    recording_sha256: str


class AuditEntry(BaseModel):
    id: int
    at: str
    operator: str | None
    action: str
    device_id: str | None
    session_id: str | None
    detail: dict[str, Any] | None
