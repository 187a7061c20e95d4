"""A guided session's full state as one typed snapshot: what every SSE event and GET /sessions/{id} carry."""

from __future__ import annotations

from typing import Protocol

from calib.json_safe import finite
from calib.judge.acceptance import turn_accuracy
from calib.judge.judgement import Judgement
from calib.result import CalibrationResult
from calib.stages.stage import AXES

from ..store import StoredSession
from .buffer import SampleBuffer
from .codes import STEPS, EndReason, Phase, State, known_reason
from .snapshot_schema import CausedBy, LiveReading, SessionOut, SessionWarning
from .turn_watch import LiveAngle
from .turns import TurnRecord


class SessionView(Protocol):
    """What a snapshot reads of a session (server.live.session.GuidedSession)."""

    id: str
    device_id: str
    state: State
    phase: Phase | None
    attempt: int
    max_attempts: int
    prompt: str
    live_reading: LiveReading
    t_now: float
    turns: dict[str, TurnRecord]
    warnings: list[SessionWarning]
    reason_code: EndReason | None
    reason: str | None
    result: CalibrationResult | None
    passed: bool | None
    judgement: Judgement | None
    decision: str | None
    calibration_id: int | None
    method: str
    lost_samples: int
    refused_samples: int
    service_late_s: float
    started_at: str
    ended_at: str | None
    caused_by: CausedBy | None
    kit_id: str | None

    @property
    def buf(self) -> SampleBuffer: ...

    @property
    def axis(self) -> str | None: ...

    @property
    def fs(self) -> float | None: ...

    @property
    def silent(self) -> bool: ...

    def still_target(self) -> float | None: ...

    def time_left_s(self) -> float | None: ...

    @property
    def live_angle(self) -> LiveAngle: ...


def session_snapshot(s: SessionView, event: str) -> SessionOut:
    """The snapshot of ``s``, sent as event ``event``."""
    progress = None
    target = s.still_target()
    live = s.live_reading
    if target is not None:
        still_s = float(live.still_s)
        progress = {"still_s": round(still_s, 3), "target_s": target, "fraction": round(min(1.0, still_s / target), 3)}
    axis = s.axis
    angle = live.angle_deg
    raw = live.raw_angle_deg
    return SessionOut.model_validate(finite({
        "session_id": s.id,
        "device_id": s.device_id,
        "kit_id": s.kit_id if s.ended_at is None else None,  # as the store keeps an ended session: without it
        "event": event,
        "state": s.state,
        "phase": s.phase,
        "step": STEPS.index(s.state) if s.state in STEPS else None,
        "steps": list(STEPS),
        "axis": axis,
        "attempt": s.attempt,
        "max_attempts": s.max_attempts,
        "prompt": s.prompt,
        "progress": progress,
        "time_left_s": None if (left := s.time_left_s()) is None else round(max(0.0, left), 1),
        "live": {
            "moving": bool(live.moving),
            "still_s": round(float(live.still_s), 3),
            "angle_deg": [round(float(a), 2) for a in angle],
            "turn_angle_deg": None if axis is None else round(float(angle[AXES.index(axis)]), 2),
            "raw_turn_angle_deg": None if axis is None else round(float(raw[AXES.index(axis)]), 2),
            "angle_calibrated": s.live_angle.calibrated,
            "target_deg": s.live_angle.target_deg,
            "t_device_s": round(s.t_now, 4),
        },
        "turns": {a: tr.to_dict() for a, tr in s.turns.items()},
        "warnings": [w.model_dump() for w in s.warnings],
        "reason_code": s.reason_code,
        "reason": s.reason,
        "result": None if s.result is None else s.result.to_json(),
        "passed": s.passed,
        "checks": [] if s.judgement is None else s.judgement.checks_json(),
        "departures": [] if s.judgement is None else s.judgement.departures_json(),
        "accuracy": None if s.judgement is None else s.judgement.accuracy,
        "decision": s.decision,
        "calibration_id": s.calibration_id,
        "method": s.method,
        "samples": s.buf.n,
        "lost_samples": s.lost_samples,
        "refused_samples": s.refused_samples,
        "service_late_s": round(s.service_late_s, 3),  # how long the service itself did not run (a starved process)
        "silent": s.silent,
        "sample_rate_hz": s.fs,
        "started_at": s.started_at,
        "ended_at": s.ended_at,
        "caused_by": None if s.caused_by is None else s.caused_by.model_dump(),
    }))


def stored_snapshot(row: StoredSession) -> SessionOut:
    """The snapshot of a session as the store keeps it (a session that ended, or runs on another gateway)."""
    info = row.get("info") or {}
    return SessionOut.model_validate(finite({
        "session_id": row["id"],
        "device_id": row["device_id"],
        "kind": row["kind"],
        "event": "state",
        "state": row["state"],
        "phase": None,
        "prompt": row.get("reason"),
        "reason_code": known_reason(row["reason_code"]),
        "reason": row["reason"],
        "result": row["result"],
        "passed": row["passed"],
        "checks": info.get("checks") or [],
        "departures": info.get("departures") or [],
        # as judged when it ended (against the calibration in force then); sessions stored before: from the result
        "accuracy": info.get("accuracy") or (turn_accuracy(row["result"]) if row["result"] else None),
        "warnings": info.get("warnings") or [],
        "turns": info.get("turns") or {},
        "decision": row["decision"],
        "calibration_id": None,
        "method": row["method"],
        "operator": row["operator"],
        "started_at": row["started_at"],
        "ended_at": row["ended_at"],
    }))
