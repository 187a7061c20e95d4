"""The API's request and response bodies (pydantic), as published in the OpenAPI schema."""

from __future__ import annotations

from enum import Enum
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from calib.apply.identity import IdentityCheckJson
from calib.estimators.registry import method_names
from calib.judge.acceptance import Check
from calib.judge.departure import Departure
from calib.quality import AccelerometerQuality
from calib.result_schema import ResultDoc
from wearable_protocol import IDENTIFY_MAX_S
from wearable_protocol.models import IDENTIFY_DEFAULT_S

from .lifecycle import CalibrationDue
from .live.codes import EndReason, State
from .live.snapshot_schema import CHECKS_TEXT, TurnAccuracy
from .store.chain import BrokenLink
from .store.records import CalibrationRecord

Method = Enum("Method", {m: m for m in method_names()}, type=str)  # type: ignore[misc]
Method.__doc__ = "An estimator: closure (the default, at the noise floor) or paper (the paper's Algorithm 1)."

Vec3 = list[float]


class Problem(BaseModel):
    """An error: what is wrong and how to fix it."""

    detail: str | list[Any]
    code: str | None = Field(None, description="a recording that could not be read or calibrated: why, in a word (as the "
                                               "command line's error code: bad_recording, bad_sections, turn_missing, ...)")


class Integrity(BaseModel):
    """The last verification of the hash chains over the store's history."""

    ok: bool
    rows: dict[str, int] = Field(description="rows verified per chain")
    first_broken_link: BrokenLink | None = Field(description="the first place a chain does not hold: chain (calibrations, "
                                                             "recordings or audit_log), seq (the row's place in its chain, 1 = "
                                                             "first), row_id, problem")
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
    K: list[Vec3] | None = Field(None, description="the full K (rows), where the simulated sensor's axes may not be "
                                 "orthogonal (a simulated kit)")


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
    model: str | None = Field(None, description="the protocol gyrocal speaks with it: gyrocal, polar-pmd, metawear, thingy52 or "
                                                "movella-dot (null: not known yet)")
    model_label: str | None = None
    sample_rate_hz: float | None = Field(None, description="the rate it streams at, Hz (read once connected, else the model's)")
    gyro_full_scale_dps: int | None = Field(None, description="its gyro range, deg/s (read once connected, else the model's)")
    time_stamps: Literal["device", "arrival"] | None = Field(None, description="device: the device's clock; arrival: the "
                                                                               "times samples reached the service")
    loss_detection: Literal["counter", "time_stamps", "none"] | None = None
    limitations: list[str] = Field(default_factory=list, description="what this device's protocol cannot tell")
    write_back: bool = Field(False, description="it can hold a calibration written to it (POST /devices/{id}/calibration/write)")
    identify: str | None = Field(None, description="what it does when asked which one it is (POST /devices/{id}/identify): "
                                                   "'blinks its light', ...; null: its protocol has no such command")
    held_calibration_id: int | None = Field(None, description="the calibration the device last said it holds")
    held_reported_at: str | None = Field(None, description="when it last said so (null: never asked)")
    held_state: Literal["current", "other", "none"] | None = Field(
        None, description="current: it holds the current calibration; other: it holds another one (write the current one "
                          "to it); none: it holds none; null: not known")
    active_session: str | None = None
    active_kit: str | None = Field(None, description="the kit session that holds it, when it is calibrated with others in "
                                                     "one tray (GET /sessions/{active_kit} shows the kit)")
    unsaved_session: str | None = Field(None, description="its latest session ended in a PASS nobody has accepted or "
                                                          "discarded yet: the result waiting to be saved")
    unsaved_kit: str | None = Field(None, description="the kit session that unsaved result was part of: save or discard it "
                                                      "there, with its kit's other wearables (GET /sessions/{unsaved_kit})")
    current_calibration: CalibrationRecord | None = None
    calibration_due: CalibrationDue | None = Field(None, description="whether the device should be calibrated again before "
                                                   "a study: never calibrated, switched on again since its calibration, or "
                                                   "its calibration older than the limit")
    power_up: PowerUpOut | None = Field(None, description="the power-up the device last reported (null: it reports none, or "
                                        "has not been connected)")
    last_seen: str | None = None


class SessionSummary(BaseModel):
    """A session in a device's list: what it was and how it ended."""

    id: str
    kind: str
    state: State
    reason_code: EndReason | None = None
    passed: bool | None = None
    decision: Literal["accepted", "discarded"] | None = None
    started_at: str | None = None
    ended_at: str | None = None


class DeviceDetail(DeviceOut):
    simulated_truth: Truth | None = Field(None, description="the simulated sensor's true parameters (simulated devices only)")
    simulated_identifying: bool | None = Field(None, description="whether the simulated wearable's light blinks now "
                                                                 "(simulated devices only)")
    info: dict[str, Any] = Field(default_factory=dict, description="what the device told the service about itself "
                                                                   "(free-form: each model tells different things)")
    recent_sessions: list[SessionSummary] = Field(default_factory=list, description="its last 10 sessions, newest first")


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


class KitStart(BaseModel):
    """The wearables of one tray to calibrate together (each once)."""

    model_config = ConfigDict(extra="forbid")
    devices: list[str] = Field(min_length=2, max_length=20, description="the wearables' ids, at least two")
    max_attempts: int | None = Field(None, ge=1, le=5, strict=True, description="tries per turn before a wearable's "
                                     "session fails (default 3)")


class KitMemberStarted(BaseModel):
    device_id: str
    session_id: str = Field(description="the wearable's own session (GET /sessions/{session_id})")


class KitStarted(BaseModel):
    session_id: str = Field(description="the kit's session: GET /sessions/{session_id} shows it with every wearable")
    devices: list[KitMemberStarted]
    state: State
    url: str


class KitAcceptOut(BaseModel):
    session_id: str
    calibrations: list[CalibrationRecord] = Field(description="one per wearable that passed: each its device's calibration now")
    not_accepted: dict[str, str] = Field(default_factory=dict, description="the wearables that did not pass, and why")


SENSOR_TEXT = r"^[^\x00-\x1f\x7f]*$"  # printable text: no NUL or other control characters


class DecisionIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    note: str | None = Field(None, max_length=1000, pattern=r"^[^\x00]*$")
    sensor_model: str | None = Field(None, min_length=1, max_length=128, pattern=SENSOR_TEXT,
                                     description="the sensor an uploaded recording came from (accept only; kept with the calibration)")
    firmware: str | None = Field(None, min_length=1, max_length=128, pattern=SENSOR_TEXT)


class IdentifyIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    seconds: int = Field(IDENTIFY_DEFAULT_S, ge=1, le=IDENTIFY_MAX_S, description="how long it blinks, s")


class IdentifyOut(BaseModel):
    device_id: str
    seconds: int = Field(description="how long it blinks, s")
    how: str = Field(description="what the wearable does: 'blinks its light', 'breathes its LED green', ...")
    message: str = Field(description="what the page says: '<name> blinks its light for 5 s.'")


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
    accelerometer: AccelerometerQuality | None = Field(None, description="as quality.accelerometer")
    passed: bool
    checks: list[Check] = Field(description=CHECKS_TEXT)
    accuracy: TurnAccuracy | None = None
    departures: list[Departure] = Field(default_factory=list, description="as a session's departures")
    reason: str | None = None
    recording_sha256: str


class GatewayOut(BaseModel):
    name: str
    url: str | None = Field(None, description="where its pages are")
    version: str | None = None
    started_at: str | None = None
    heartbeat_at: str | None = Field(None, description="when it last said it is alive")
    alive: bool = Field(description="it said so within the fleet's silence limit")
    this: bool = Field(description="the gateway that answered this request")


class SightingOut(BaseModel):
    gateway: str
    last_seen: str | None = None
    rssi_dbm: int | None = Field(None, description="signal strength at that gateway, dBm (null: the radio does not say)")


class CalibrationStatus(BaseModel):
    status: Literal["never", "due", "current"]
    reason: str
    calibration_id: int | None = None


class FleetDevice(BaseModel):
    id: str
    name: str | None = None
    gateway: str | None = Field(None, description="the gateway that holds it, or saw it last")
    last_seen: str | None = None
    seen_by: list[SightingOut] = Field(description="every gateway that sees it, the latest first")
    in_session: bool
    session: str | None = Field(None, description="what holds it: a session or verification id")
    activity: Literal["calibration", "verification", "write"] | None = None
    lease_expires_at: str | None = None
    calibration: CalibrationStatus
    wizard_url: str = Field(description="the page that calibrates it, on the gateway that can reach it")


class FleetOut(BaseModel):
    """Every gateway sharing the store and every wearable they see."""

    this_gateway: str | None
    gateways: list[GatewayOut]
    devices: list[FleetDevice]
    at: str = Field(description="when this view was read (ISO 8601, UTC)")


class TurnSpan(BaseModel):
    axis: str | None
    start_s: float = Field(description="from the recording's start, s")
    end_s: float


class SectionOut(BaseModel):
    """One labelled run of a recording's samples, as imucal's section lists hold them (``calib.io.sections``)."""

    label: str = Field(description="still_1, still_2, ... for the rests; x_rot, y_rot, z_rot for the turns")
    start: int = Field(description="the first sample (a position in the recording, from 0)")
    end: int = Field(description="the sample after the last (end exclusive)")


class SessionPlot(BaseModel):
    """A session's calibration drawn: each trace before (raw readings) and after (K m + b), decimated (calib.plots)."""

    t: list[float | None] = Field(description="from the recording's start, s")
    rate_before: list[float | None] = Field(description="rate magnitude, deg/s")
    rate_after: list[float | None]
    pose_error_before: list[float | None] = Field(description="angle from the start pose, deg: 0 after each full turn "
                                                              "when calibrated")
    pose_error_after: list[float | None]
    swept_before: list[float | None] = Field(description="angle swept within each turn about its axis, deg (null "
                                                         "outside turns)")
    swept_after: list[float | None]
    turns: list[TurnSpan]
    k: Vec3
    b: Vec3 = Field(description="deg/s of true rate")
    method: str


class RollPitchYaw(BaseModel):
    roll: list[float]
    pitch: list[float]
    yaw: list[float]


class OrientationOut(BaseModel):
    """An uploaded recording's orientation before and after the calibration in force for it (deg, unwrapped)."""

    calibration_id: int
    warnings: list[str] = Field(description="what makes the calibration doubtful for this recording")
    identity_check: IdentityCheckJson | None = None
    method: str = Field(description="how the orientation was estimated (Madgwick with the accelerometer, or the gyro "
                                    "integrated)")
    t: list[float] = Field(description="s")
    before: RollPitchYaw
    after: RollPitchYaw
    difference_deg: list[float] = Field(description="the angle between the two orientations")
    final_difference_deg: float
