"""A session's snapshot as a typed object: what every SSE event, GET /sessions/{id} and the gateways' relay carry."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from calib.judge.acceptance import Check
from calib.judge.departure import Departure
from calib.judge.verification import TurnVerification
from calib.result_schema import ResultDoc
from calib.watch.schema import WatchOut

from .codes import EndReason, Phase, State

Vec3 = list[float]


@dataclass
class LiveReading:
    """What the device reads now: how long it has rested (s), whether it moves, the turn's angles about x, y, z (deg,
    with the live calibration if any, and raw)."""

    still_s: float = 0.0
    moving: bool = False
    angle_deg: Vec3 = field(default_factory=lambda: [0.0, 0.0, 0.0])
    raw_angle_deg: Vec3 = field(default_factory=lambda: [0.0, 0.0, 0.0])


class SessionWarning(BaseModel):
    """Something the clinician should know that did not end the session."""

    code: str = Field(description="what happened, for a program (e.g. bumped, too_fast, service_late)")
    message: str = Field(description="what happened, in the clinician's words")
    t_device_s: float = Field(description="the device's time when it happened, s")
    at: str = Field(description="when it happened (ISO 8601, UTC)")
    device_id: str | None = Field(None, description="in a kit's warnings, the wearable it is of (its link, its data, "
                                                    "a turn of its own, loose in its slot); null when it is the tray's")


class StillProgress(BaseModel):
    """How far a rest the session waits for has come."""

    still_s: float
    target_s: float
    fraction: float = Field(description="still_s / target_s, at most 1")


class LiveOut(BaseModel):
    """The device's live reading as the page shows it."""

    moving: bool
    still_s: float = Field(description="how long the device has rested, s")
    angle_deg: Vec3 = Field(description="the turn's angle about x, y, z so far, deg")
    turn_angle_deg: float | None = Field(None, description="the angle about the axis being turned, deg")
    raw_turn_angle_deg: float | None = Field(None, description="the same from the raw readings (no calibration), deg")
    angle_calibrated: bool = Field(description="the angle uses the device's accepted calibration")
    target_deg: float | None = Field(None, description="a full turn, when the angle is calibrated (else no target)")
    t_device_s: float = Field(description="the device's time of the last reading, s")


class TurnOut(BaseModel):
    """A turn that passed its checks."""

    axis: Literal["x", "y", "z"]
    angle_deg: Vec3 = Field(description="the bias-compensated raw angle turned about x, y, z, deg")
    duration_s: float
    start_s: float
    end_s: float
    rest_before_s: float = Field(description="how long the device rested before the turn, s")
    gravity_change_deg: float | None = Field(None, description="gravity before vs after the turn: 0 when put back in place")


class CausedBy(BaseModel):
    """The batch of readings a snapshot answers: for measuring how late the page is."""

    t_device_s: float
    received_at: float = Field(description="when the service received it (Unix time, s)")


class RemoteGateway(BaseModel):
    """Where a session of another gateway runs."""

    gateway: str
    url: str | None = Field(None, description="the address its pages are at (null: not known)")


class TurnAccuracy(BaseModel):
    """How well a full turn measures, the worst of the session's turns, before and after the calibration."""

    before_deg: float = Field(description="how far from 360° a full turn read with what the device used until now: its "
                                          "calibration in force, or the raw readings (bias removed) when it had none")
    after_deg: float = Field(description="how far from where it began a turn ends, measured with this calibration")
    before_with: Literal["calibration", "raw"] = Field("raw", description="what before_deg was measured with")
    before_calibration_id: int | None = Field(None, description="the calibration in force it was measured with")


CHECKS_TEXT = ("each tolerance check: name, axis, value, limit, ok, text, used (the share of the allowance the value "
               "uses: 0 ideal, 1 at the limit) and near_limit (passed with used >= 0.8)")


DEPARTURES_TEXT = ("the result's parameters that the device's own earlier calibrations (two at least) do not explain: "
                   "name, axis, value, history_mean, history_spread, z, n_history, text (a dropped or damaged sensor)")


class KitDeviceOut(BaseModel):
    """One wearable of a kit session: its own session's state and result (GET /sessions/{its session_id} has the rest)."""

    device_id: str
    session_id: str
    state: State
    phase: Phase | None = None
    prompt: str | None = None
    reason_code: EndReason | None = None
    reason: str | None = None
    result: ResultDoc | TurnVerification | WatchOut | None = None
    passed: bool | None = None
    checks: list[Check] = Field(default_factory=list, description=CHECKS_TEXT)
    accuracy: TurnAccuracy | None = Field(None, description="a full turn before and after its calibration")
    departures: list[Departure] = Field(default_factory=list, description=DEPARTURES_TEXT)
    decision: Literal["accepted", "discarded"] | None = None
    calibration_id: int | None = None
    samples: int | None = None
    lost_samples: int | None = None
    departed: bool = Field(False, description="it came apart from the kit (moved in its slot): no result; redo it")


class KitMemberConsistency(BaseModel):
    """How one wearable followed its kit: the coupling's residual against its noise (deg/s, per axis) and how far its
    attitude came apart from the others' (``calib.kit.departure``)."""

    residual_dps: list[float | None]
    noise_dps: list[float | None]
    residual_ratio: float | None = Field(None, description="the coupling's rms residual over the noise's: about 1")
    angle_deg: float | None = Field(None, description="the largest angle its attitude came apart from the others', deg")
    std_deg: float | None = Field(None, description="what the noise allows of that angle (1 sigma), deg")
    p_value: float | None = Field(None, description="the chance of an angle this large from the noise alone")
    at_s: float | None = Field(None, description="when it came apart (the reference's clock, s)")
    departed: bool = False
    burst_dps: float | None = Field(None, description="the largest rms of its rate against the others' over a quarter "
                                    "second, deg/s (a wearable moving in its slot)")
    step_deg: float | None = Field(None, description="how far it turned in its slot across that burst, when the tray "
                                   "rested through it (a slip there shows less at the rests), deg")


class KitAxesOut(BaseModel):
    """The kit's sensor axes (``calib.kit.axes``): a full (upper-triangular) K for every wearable, or diagonal."""

    model: str = Field(description="upper-triangular: the wearables' axes are not orthogonal alike; diagonal otherwise")
    chi2: float | None = Field(None, description="the wearables' tilts about their mean against their noise")
    dof: int = Field(0, description="its degrees of freedom, 3 (N - 1)")
    p_value: float | None = Field(None, description="the chance of tilts this different from the noise alone")
    tilt_spread: float | None = Field(None, description="the spread (sd) of the wearables' tilts")
    largest_tilt: float | None = Field(None, description="the largest cross-axis term of any wearable's K (|K_ij| / "
                                       "K_jj above the diagonal); none when every K is diagonal")
    reason: str = Field(description="why this model, and how the kit's common tilt was fixed")


class KitConsistency(BaseModel):
    """The kit's consistency: the reference wearable, each wearable's, who departed, who did not turn with the kit at
    all (left out of it), and the kit's axes."""

    reference: str
    devices: dict[str, KitMemberConsistency | None]
    departed: list[str]
    not_turned: list[str] = Field(default_factory=list, description="the wearables whose readings follow none of the "
                                  "others' motion (not in the tray, or not switched on): left out of the kit")
    axes: KitAxesOut | None = None


class KitOut(BaseModel):
    """A kit session's consistency: how each wearable followed the tray (calib.kit), and which departed."""

    consistency: KitConsistency | None = Field(None, description="per wearable: the coupling's residual against its "
                                               "noise and its departure")
    departed: list[str] = Field(default_factory=list, description="the wearables that came apart from the kit")
    refusal: str | None = Field(None, description="why the kit could not be calibrated together, if it could not")


class SessionOut(BaseModel):
    """A full snapshot of a session: what every SSE event carries too."""

    model_config = ConfigDict(extra="forbid")
    session_id: str
    device_id: str
    kind: Literal["live", "upload", "import", "verify", "watch", "kit"] = "live"
    kit_id: str | None = Field(None, description="while a wearable's live session that is part of a kit runs: that "
                                                 "kit's session (GET /sessions/{kit_id}), whose prompts, said of the tray, "
                                                 "are the ones to follow")
    event: str = Field("state", description="the SSE event this snapshot was sent as (state, prompt, live, warning, "
                                            "result, decision)")
    event_id: int | None = Field(None, description="its number in the session's event stream")
    state: State = Field(description="where the session is (protocol order, then reconnecting, computing and the end states)")
    phase: Phase | None = None
    step: int | None = Field(None, description="the index of state in steps (null: not a protocol step)")
    steps: list[State] = Field(default_factory=list, description="the protocol's steps, in order")
    axis: Literal["x", "y", "z"] | None = Field(None, description="the axis being turned")
    attempt: int | None = Field(None, description="the try of the current turn, from 1")
    max_attempts: int | None = None
    prompt: str | None = None
    progress: StillProgress | None = Field(None, description="the rest being waited for, if any")
    time_left_s: float | None = Field(None, description="how long (device s) the session waits for the turn or the rest "
                                      "asked for before it ends for want of it; null while nothing is waited for")
    live: LiveOut | None = None
    turns: dict[str, TurnOut] = Field(default_factory=dict, description="the turns recorded, by axis")
    warnings: list[SessionWarning] = Field(default_factory=list)
    reason_code: EndReason | None = Field(None, description="why the session ended, if not done")
    reason: str | None = None
    result: ResultDoc | TurnVerification | WatchOut | None = Field(
        None, description="the estimator's result (its form numbered by format_version); a verification session's turn; a "
                          "watch's report")
    passed: bool | None = None
    checks: list[Check] = Field(default_factory=list, description=CHECKS_TEXT)
    accuracy: TurnAccuracy | None = Field(None, description="a full turn before and after the calibration (closure estimator)")
    departures: list[Departure] = Field(default_factory=list, description=DEPARTURES_TEXT)
    decision: Literal["accepted", "discarded"] | None = None
    calibration_id: int | None = None
    method: str | None = None
    operator: str | None = None
    samples: int | None = Field(None, description="readings recorded so far")
    lost_samples: int | None = Field(None, description="readings lost on the radio link")
    refused_samples: int | None = Field(None, description="readings the wearable sent in malformed packets, which the "
                                        "link refused (its firmware's doing, not the radio's)")
    service_late_s: float | None = Field(None, description="how long the service itself did not run (a starved process), s")
    silent: bool | None = Field(None, description="no data from the device for a while though its link is up (the "
                                "warning no_data), until its data comes again")
    sample_rate_hz: float | None = None
    started_at: str | None = None
    ended_at: str | None = None
    caused_by: CausedBy | None = None
    remote: RemoteGateway | None = Field(None, description="the gateway the session runs on, when not this one")
    stored: bool | None = Field(None, description="a live session that ended: whether the store has its outcome and "
                                                  "recording yet (false: kept by the service and written when it can)")
    store_error: str | None = Field(None, description="why the store could not take them yet (its disk full, ...)")
    devices: list[KitDeviceOut] = Field(default_factory=list, description="a kit session: each wearable's own session")
    kit: KitOut | None = Field(None, description="a kit session: the kit's consistency and who departed")
