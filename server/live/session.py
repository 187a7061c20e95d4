"""The guided calibration session: a state machine fed by the streaming stage detector.

States (in protocol order): connecting -> still -> turn_x -> turn_y -> turn_z -> computing -> done,
with reconnecting while the link is down, and the end states done, failed, cancelled. Turn states
have phases: settle (rest again after a reconnection or a retry), ready (prompting the turn),
turning (live angle), pause (rest after the checked turn). Every change is reported to a listener
as a full snapshot; the listener (server.events) numbers them and streams them as SSE.

The machine is synchronous and knows no I/O: the runner (server.runner) feeds it sample batches,
link events and clock ticks, and runs the estimator when the state reaches computing.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from datetime import UTC, datetime
from typing import Any, cast

import numpy as np

from calib.acceptance import evaluate
from calib.recording import Recording, RecordingMeta
from calib.result import CalibrationResult
from calib.stage import AXES, Axis, Stage
from calib.turn_checks import gravity_change_deg, rest_after_full_turn, swept_angles

from ..config import Settings
from . import guidance as say
from .buffer import SampleBuffer
from .codes import END_STATES, STEPS, TURN_STATES
from .turns import TurnRecord

Listener = Callable[[str, dict[str, Any]], None]


def _utc() -> str:
    return datetime.now(UTC).isoformat()


class GuidedSession:
    """One guided calibration of one device."""

    def __init__(
        self,
        session_id: str,
        device_id: str,
        settings: Settings,
        tracker_factory: Callable[[float, float | None], Any] | None = None,
        listener: Listener | None = None,
        max_attempts: int | None = None,
        method: str | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.id = session_id
        self.device_id = device_id
        self.settings = settings
        self.timings = settings.timings
        self.tol = settings.tolerances
        self.method = method or settings.method
        self.max_attempts = max(1, int(max_attempts or settings.max_turn_attempts))
        self._tracker_factory = tracker_factory or _default_tracker
        self.listener = listener
        self.clock = clock

        self.state = "connecting"
        self.phase: str | None = None
        self.prompt = say.PROMPTS["connecting"]
        self.started_at = _utc()
        self.started_mono = clock()
        self.ended_at: str | None = None
        self.reason_code: str | None = None
        self.reason: str | None = None
        self.warnings: list[dict[str, Any]] = []
        self.result: dict[str, Any] | None = None
        self.passed: bool | None = None
        self.checks: list[dict[str, Any]] = []
        self.decision: str | None = None
        self.calibration_id: int | None = None
        self.attempt = 1
        self.device_info: dict[str, Any] = {}

        self.fs: float | None = None
        self.fs_estimate: float | None = None  # the link's estimate of the true rate from device time
        self.full_scale: float | None = None
        self.buf = SampleBuffer()
        self.tracker: Any = None
        self._offset = 0  # global index of the current tracker's sample 0
        self._t_first: float | None = None  # device time of the session's first sample
        self._clock_from_next = True  # the current phase's time limit counts from the next sample received
        self._last_t: float | None = None
        self._t_shift = 0.0
        self.lost_samples = 0

        self._still_stages: list[Stage] = []
        self._last_still: Stage | None = None
        self.turns: dict[str, TurnRecord] = {}
        self._axis_i = 0
        self._phase_since_t = 0.0
        self._hinted = False
        self._turn_lost = 0
        self._resume: tuple[str, str | None] | None = None
        self._resume_phase = "ready"  # what a settle phase leads to: the turn again, or the pause
        self._provisional: str | None = None  # a turn started before the countdown ended: "initial" | "pause"
        self._rest_before_s = 0.0
        self._rested_after_turn = False
        self._link_lost_mono: float | None = None
        self._live: dict[str, Any] = {"still_s": 0.0, "moving": False, "angle_deg": [0.0, 0.0, 0.0]}
        self._t_now = 0.0
        self._caused_by: dict[str, Any] | None = None
        self._last_live_emit = -1e9
        self.snapshot_count = 0
        self._emitted_state: str | None = None

    # -- public properties ------------------------------------------------------------------------
    @property
    def finished(self) -> bool:
        return self.state in END_STATES

    @property
    def axis(self) -> str | None:
        return AXES[self._axis_i] if self.state in TURN_STATES.values() else None

    @property
    def retry_allowed(self) -> bool:
        return self.attempt < self.max_attempts

    # -- inputs from the runner -------------------------------------------------------------------
    def connected(self, fs: float, info: dict[str, Any] | None = None, full_scale_dps: float | None = None) -> None:
        """The link is up and streaming at fs Hz: start waiting for the initial rest."""
        if self.finished:
            return
        self.fs = float(fs)
        self.full_scale = float(full_scale_dps) if full_scale_dps else None
        self.device_info = dict(info or {})
        self._new_tracker()
        self._set_state("still", "waiting", say.PROMPTS["still"])

    def feed(
        self,
        t: np.ndarray,
        gyro: np.ndarray,
        accel: np.ndarray | None = None,
        seq: np.ndarray | None = None,
        lost_before: int = 0,
        received_at: float | None = None,
    ) -> None:
        """One batch of samples (device time t in s, raw gyro in deg/s, accel in g)."""
        if self.finished or self.state in ("computing", "reconnecting", "connecting") or self.tracker is None:
            return
        t = np.asarray(t, dtype=float).reshape(-1)
        if t.size == 0:
            return
        gyro = np.asarray(gyro, dtype=float).reshape(-1, 3)
        accel = None if accel is None else np.asarray(accel, dtype=float).reshape(-1, 3)
        seq = None if seq is None else np.asarray(seq, dtype=np.int64).reshape(-1)
        t = self._monotonic_time(t)
        self._caused_by = {"t_device_s": float(t[-1]), "received_at": received_at if received_at is not None else time.time()}
        if self._t_first is None:
            # samples missing before the first are not part of this session's recording (e.g. the time
            # between two sessions on one link)
            self._t_first = float(t[0])
            lost_before = 0
        if self._clock_from_next:
            # A device's clock does not start at 0 (it keeps running between sessions) and runs on while
            # the link is down: the time limits count from the session's first sample, and after a
            # reconnection from the first sample that came back.
            self._clock_from_next = False
            self._phase_since_t = float(t[0])
        if lost_before:
            self.lost_samples += int(lost_before)
            if self.phase == "turning":
                self._turn_lost += int(lost_before)
        self.buf.append(t, gyro, accel, seq)
        self._t_now = float(t[-1])
        try:
            events = self.tracker.feed(t, gyro, seq)
            for ev in events:
                self._on_event(ev)
                if self.finished or self.state == "computing":
                    return
            self._update_live()
            self._check_time_limits()
        finally:
            # only what this batch causes carries it; later snapshots (result, decision) do not
            self._caused_by = None

    def link_lost(self) -> None:
        """The radio link dropped: pause; the current turn is redone after reconnection."""
        if self.finished or self.state in ("computing", "reconnecting"):
            return
        if self.state == "connecting":
            return
        self._resume = (self.state, self.phase)
        self._link_lost_mono = self.clock()
        self._warn("link_lost", say.PROMPTS["reconnecting"])
        self._set_state("reconnecting", None, say.PROMPTS["reconnecting"])

    def link_restored(self) -> None:
        """The link is back: rest again, then redo the step that was interrupted."""
        if self.state != "reconnecting" or self._resume is None:
            return
        state, phase = self._resume
        self._resume = None
        self._link_lost_mono = None
        self._clock_from_next = True  # the device's clock ran on while the link was down
        # the tracker carries on across the gap (its noise floor stays valid); the interrupted motion
        # closes with a counter_gap flag while the session waits for rest and is not used
        if state == "still":
            self._set_state("still", "waiting", say.PROMPTS["still"])
            return
        axis = AXES[self._axis_i]
        if phase == "pause":
            # the turn was recorded already; only the pause is done again
            self._warn("link_restored", say.link_restored(None))
        else:
            self._warn("link_restored", say.link_restored(axis))
        self._set_state(state, "settle", say.PROMPTS["settle"])
        self._resume_phase = "pause" if phase == "pause" else "ready"

    def tick(self) -> None:
        """Wall-clock checks: the reconnection limit and the overall watchdog."""
        if self.finished:
            return
        now = self.clock()
        if self.state == "reconnecting" and self._link_lost_mono is not None:
            if now - self._link_lost_mono > self.settings.reconnect_timeout_s:
                self.fail("link_lost", say.link_lost(self.settings.reconnect_timeout_s))
                return
        if now - self.started_mono > self.settings.session_timeout_s:
            self.fail("timeout", say.timeout(self.settings.session_timeout_s))

    def cancel(self, reason: str = "Cancelled by the operator.") -> bool:
        if self.finished:
            return False
        self.reason_code = "cancelled"
        self.reason = reason
        self._end("cancelled", reason)
        return True

    def fail(self, code: str, message: str) -> None:
        if self.finished:
            return
        self.reason_code = code
        self.reason = message
        self._end("failed", message)

    # -- computing --------------------------------------------------------------------------------
    def recording(self) -> Recording:
        """Everything received so far as a Recording (device time, raw readings)."""
        info = self.device_info
        meta = RecordingMeta(
            sample_rate_hz=self.fs_estimate or self.fs,
            device_id=self.device_id,
            sensor_model=info.get("sensor_model"),
            gyro_full_scale_dps=self.full_scale,
            source=f"session {self.id}",
        )
        return self.buf.recording(meta)

    def protocol_stages(self) -> list[Stage]:
        """The stages the estimator gets: every still, and the turns that passed their checks."""
        stages = list(self._still_stages)
        if self.tracker is not None:
            for st in self.tracker.finish():
                if getattr(st, "kind", None) == "stage_closed":
                    st = st.stage
                if isinstance(st, Stage) and st.kind == "still":
                    stages.append(self._globalise(st))
        turns = [
            Stage("turn", tr.start, tr.end, tr.start_s, tr.end_s, cast(Axis, tr.axis), float(tr.angle_deg[AXES.index(tr.axis)]), tr.flags)
            for tr in self.turns.values()
        ]
        stills = _dedupe([s for s in stages if s.kind == "still"])
        # a still must not overlap an accepted turn
        stills = [s for s in stills if not any(s.start < tr.end and tr.start < s.end for tr in turns)]
        return sorted(stills + turns, key=lambda s: s.start)

    def set_result(self, result: CalibrationResult, shown: dict[str, Any] | None = None) -> None:
        """The estimator's result: judge it against the tolerances, then done or failed. ``shown`` is its JSON form
        (with the recording's rate and length), as the page and the store get it; default ``result.to_dict()``."""
        if self.finished:
            return
        self.result = shown if shown is not None else result.to_dict()
        self.checks = evaluate(result, self.tol)
        failures = [c["text"] for c in self.checks if not c["ok"]]
        self.passed = not failures
        if failures:
            self.fail("out_of_tolerance", say.out_of_tolerance(failures))
            return
        self._end("done", say.done_prompt(True))

    # -- snapshots --------------------------------------------------------------------------------
    def snapshot(self, event: str = "state") -> dict[str, Any]:
        """The full state of the session, as every SSE event and GET /sessions/{id} carry it."""
        progress = None
        target = self._still_target()
        if target is not None:
            still_s = float(self._live["still_s"])
            progress = {"still_s": round(still_s, 3), "target_s": target, "fraction": round(min(1.0, still_s / target), 3)}
        axis = self.axis
        angle = self._live["angle_deg"]
        return {
            "session_id": self.id,
            "device_id": self.device_id,
            "event": event,
            "state": self.state,
            "phase": self.phase,
            "step": STEPS.index(self.state) if self.state in STEPS else None,
            "steps": list(STEPS),
            "axis": axis,
            "attempt": self.attempt,
            "max_attempts": self.max_attempts,
            "prompt": self.prompt,
            "progress": progress,
            "live": {
                "moving": bool(self._live["moving"]),
                "still_s": round(float(self._live["still_s"]), 3),
                "angle_deg": [round(float(a), 2) for a in angle],
                "turn_angle_deg": None if axis is None else round(float(angle[AXES.index(axis)]), 2),
                "t_device_s": round(self._t_now, 4),
            },
            "turns": {a: tr.to_dict() for a, tr in self.turns.items()},
            "warnings": list(self.warnings),
            "reason_code": self.reason_code,
            "reason": self.reason,
            "result": self.result,
            "passed": self.passed,
            "checks": self.checks,
            "decision": self.decision,
            "calibration_id": self.calibration_id,
            "method": self.method,
            "samples": self.buf.n,
            "lost_samples": self.lost_samples,
            "sample_rate_hz": self.fs,
            "started_at": self.started_at,
            "ended_at": self.ended_at,
            "caused_by": self._caused_by,
        }

    def decide(self, decision: str, calibration_id: int | None) -> None:
        """The operator accepted or discarded the result (already written to the store)."""
        self.decision = decision
        self.calibration_id = calibration_id
        if decision == "accepted":
            self.prompt = "Calibration accepted: it is now the device's current calibration."
        else:
            self.prompt = "Result discarded: the device keeps its previous calibration."
        self._emit("decision")

    def publish(self) -> None:
        """Send the current snapshot to the listener (the first event of a session)."""
        self._emit("state")

    # -- internals --------------------------------------------------------------------------------
    def _emit(self, event: str) -> None:
        if self.state != self._emitted_state:
            event = "state"
            self._emitted_state = self.state
        self.snapshot_count += 1
        if self.listener is not None:
            self.listener(event, self.snapshot(event))

    def _set_state(self, state: str, phase: str | None, prompt: str) -> None:
        changed = state != self.state
        self.state = state
        self.phase = phase
        self.prompt = prompt
        self._phase_since_t = self._t_now
        self._hinted = False
        self._emit("state" if changed else "prompt")

    def _set_phase(self, phase: str, prompt: str) -> None:
        self.phase = phase
        self.prompt = prompt
        self._phase_since_t = self._t_now
        self._hinted = False
        self._emit("prompt")

    def _warn(self, code: str, message: str, emit: bool = True) -> None:
        self.warnings.append({"code": code, "message": message, "t_device_s": round(self._t_now, 3), "at": _utc()})
        if emit:
            self._emit("warning")

    def _end(self, state: str, prompt: str) -> None:
        self.state = state
        self.phase = None
        self.prompt = prompt
        self.ended_at = _utc()
        self._emit("state")

    def _new_tracker(self) -> None:
        assert self.fs is not None
        if self.tracker is not None:
            try:
                for ev in self.tracker.finish():
                    if getattr(ev, "kind", None) == "stage_closed" and ev.stage.kind == "still":
                        self._still_stages.append(self._globalise(ev.stage))
            except Exception:  # a tracker cut short by a link loss may have nothing sensible to close
                pass
        self.tracker = self._tracker_factory(self.fs, self.full_scale)
        self._offset = self.buf.n
        self._last_still = None
        self._live = {"still_s": 0.0, "moving": False, "angle_deg": [0.0, 0.0, 0.0]}

    def _monotonic_time(self, t: np.ndarray) -> np.ndarray:
        # a reconnected device may restart its clock; keep the session's time strictly increasing
        t = t + self._t_shift
        if self._last_t is not None and t[0] <= self._last_t:
            dt = 1.0 / self.fs if self.fs else 1e-3
            shift = self._last_t + dt - t[0]
            self._t_shift += shift
            t = t + shift
        self._last_t = float(t[-1])
        return t

    def _globalise(self, st: Stage) -> Stage:
        if self._offset == 0:
            return st
        return replace(st, start=st.start + self._offset, end=st.end + self._offset)

    def _still_target(self) -> float | None:
        if self.state == "still":
            return self.timings.initial_still_s
        if self.phase == "pause":
            return self.timings.pause_s
        if self.phase == "settle":
            return self.timings.settle_s
        return None

    def _update_live(self) -> None:
        live = self.tracker.live
        moving = bool(getattr(live, "moving", False))
        still_s = 0.0 if moving else float(getattr(live, "still_for_s", 0.0) or 0.0)
        angle = np.asarray(getattr(live, "live_angle_deg", np.zeros(3)), dtype=float).reshape(-1)
        if angle.size != 3 or not np.all(np.isfinite(angle)):
            angle = np.zeros(3)
        self._live = {"still_s": still_s, "moving": moving, "angle_deg": angle.tolist()}

        if self.phase == "turning":
            axis = AXES[self._axis_i]
            if not moving and still_s >= self.timings.rest_seen_s and abs(angle[AXES.index(axis)]) >= self.tol.turn_angle_min_deg:
                self._rested_after_turn = True
            elif moving and self._rested_after_turn:
                # back at rest after a full turn, then moved again before the rest was long enough to
                # close the turn: the turn and that motion cannot be told apart any more
                self._moved_during_pause(axis)
                return

        target = self._still_target()
        if target is not None and still_s >= target:
            self._still_reached()
            return
        now = self.clock()
        if now - self._last_live_emit >= 1.0 / self.settings.sse_rate_hz:
            if self.phase == "turning":
                self._last_live_emit = now
                self._emit("angle")
            elif target is not None:
                self._last_live_emit = now
                self._emit("progress")

    def _still_reached(self) -> None:
        if self.state == "still":
            self._axis_i = 0
            self._set_state("turn_x", "ready", say.turn_prompt("x"))
            return
        axis = AXES[self._axis_i]
        if self.phase == "settle":
            resume = self._resume_phase
            self._resume_phase = "ready"
            if resume == "pause":
                self._set_phase("pause", say.pause_prompt(axis, AXES[self._axis_i + 1] if self._axis_i < 2 else None))
            else:
                self._set_phase("ready", say.turn_prompt(axis))
            return
        if self.phase == "pause":
            if self._axis_i < 2:
                self._axis_i += 1
                self.attempt = 1
                nxt = AXES[self._axis_i]
                self._set_state(TURN_STATES[nxt], "ready", say.turn_prompt(nxt))
            else:
                self._set_state("computing", None, say.PROMPTS["computing"])

    def _on_event(self, ev: Any) -> None:
        kind = getattr(ev, "kind", None)
        if kind == "stage_closed":
            st = self._globalise(ev.stage)
            if st.kind == "still":
                self._still_stages.append(st)
                self._last_still = st
            elif self.phase == "turning":
                self._check_turn(st)
            return
        if kind == "motion_started":
            self._on_motion(float(getattr(ev, "t", self._t_now)))

    def _rest_before(self, t_motion: float) -> float:
        """How long the device rested before a motion that began at t_motion (s of device time).

        Taken from the still the tracker closed at that instant, so it does not depend on how the
        samples were batched; 0 when the rest was too short to be a still segment.
        """
        still = self._last_still
        if still is None or abs(still.end_s - t_motion) > 1e-6:
            return 0.0
        return float(still.end_s - still.start_s)

    def _on_motion(self, t_motion: float) -> None:
        still_s = self._rest_before(t_motion)
        if self.state == "still":
            if still_s >= self.timings.min_rest_before_turn_s:
                # Started before the countdown ended but after enough rest: take it as the x turn if
                # it proves to be one; a mere fidget just restarts the count.
                self._provisional = "initial"
                self._rest_before_s = still_s
                self._axis_i = 0
                self._turn_lost = 0
                self._rested_after_turn = False
                self._set_state("turn_x", "turning", say.turning_prompt("x"))
                return
            if still_s > 0.2 * self.timings.initial_still_s:
                self._warn("moved", "The device moved: the count starts again. Keep it still against the block.")
            self._live["still_s"] = 0.0
            return
        if self.state not in TURN_STATES.values():
            return
        axis = AXES[self._axis_i]
        if self.phase == "ready":
            self._provisional = None
            self._rest_before_s = still_s
            self._turn_lost = 0
            self._rested_after_turn = False
            self._set_phase("turning", say.turning_prompt(axis))
        elif self.phase == "pause":
            if self._axis_i < 2:
                # the next turn, started before the countdown ended (checked when it closes)
                self._provisional = "pause"
                self._rest_before_s = still_s
                self._axis_i += 1
                self.attempt = 1
                self._turn_lost = 0
                self._rested_after_turn = False
                nxt = AXES[self._axis_i]
                self._set_state(TURN_STATES[nxt], "turning", say.turning_prompt(nxt))
            else:
                self._moved_during_pause(axis)

    def _moved_during_pause(self, axis: str) -> None:
        retry = self.retry_allowed
        recorded = axis in self.turns
        msg = say.moved_during_pause(axis, self.timings.pause_s, retry, recorded)
        if retry:
            self.attempt += 1
            self._warn("moved_during_pause", msg)
            self._set_phase("settle", say.PROMPTS["settle"])
            # a recorded turn keeps its place and only the pause is done again; otherwise the turn is asked again
            self._resume_phase = "pause" if recorded else "ready"
        else:
            self.fail("moved_during_pause", msg)

    def _rest_reading(self) -> np.ndarray | float:
        """The raw reading at rest (deg/s): the mean of the last still, 0 before there is one."""
        still = self._last_still
        return self.buf.gyro[still.start : still.end].mean(axis=0) if still is not None and still.end > still.start else 0.0

    def _turn_angles(self, start: int, end: int) -> np.ndarray:
        """Integrated raw angle (deg) about x, y, z over [start, end), bias from the last still."""
        return swept_angles(self.buf.t[start:end], self.buf.gyro[start:end], self._rest_reading())

    def _rest_after_full_turn(self, st: Stage, k: int) -> bool:
        """Whether the motion holds a rest of rest_seen_s after a full turn about axis k, then moves on."""
        if self.fs is None:
            return False
        floor = getattr(self.tracker.live, "noise_floor", None) if self.tracker is not None else None
        return rest_after_full_turn(self.buf.t[st.start : st.end], self.buf.gyro[st.start : st.end], self._rest_reading(), k, floor,
                                    self.timings.rest_seen_s, self.tol.turn_angle_min_deg)

    def _gravity_change_deg(self, st: Stage) -> float | None:
        """Angle (deg) between gravity in the rest before the turn and in the rest after it."""
        acc = self.buf.accel if self.buf.has_accel else None
        still = self._last_still
        if acc is None or still is None or self.fs is None:
            return None
        span = max(2, int(0.5 * self.fs))
        return gravity_change_deg(acc[max(still.start, still.end - span) : still.end], acc[st.end : min(self.buf.n, st.end + span)])

    def _check_turn(self, st: Stage) -> None:
        axis = AXES[self._axis_i]
        angles = self._turn_angles(st.start, st.end)
        k_got = int(np.argmax(np.abs(angles)))
        got = AXES[k_got]
        k_exp = AXES.index(axis)
        a = float(angles[k_exp])
        tol = self.tol
        if self._provisional is not None and float(np.abs(angles).max()) < 0.5 * tol.turn_angle_min_deg:
            # an early motion that was no turn at all
            if self._provisional == "initial":
                self._provisional = None
                self._warn("moved", "The device moved: the count starts again. Keep it still against the block.")
                self._axis_i = 0
                self._set_state("still", "waiting", say.PROMPTS["still"])
            else:
                self._provisional = None
                self._axis_i -= 1
                self.state = TURN_STATES[AXES[self._axis_i]]
                self._moved_during_pause(AXES[self._axis_i])
            return
        self._provisional = None
        if self._rest_after_full_turn(st, k_exp):
            # back at rest after a full turn, then moved again before the rest was long enough to close
            # the turn (the stage detector merged the two): the turn cannot be used
            self._moved_during_pause(axis)
            return
        retry = self.retry_allowed
        m = self.buf.gyro[st.start : st.end]
        saturated = "saturated" in st.flags or (
            self.full_scale is not None and m.size > 0 and float(np.abs(m).max()) >= 0.995 * self.full_scale
        )
        lost = self._turn_lost
        if not lost and "counter_gap" in st.flags:
            lost = 1
        off_axis = float(np.hypot(*np.delete(angles, k_exp)))
        gravity = self._gravity_change_deg(st)
        problem: tuple[str, str] | None = None
        if lost:
            problem = ("sample_loss", say.sample_loss(axis, lost, retry))
        elif saturated:
            problem = ("too_fast", say.too_fast(axis, self.full_scale, retry))
        elif got != axis and abs(angles[k_got]) >= 0.5 * tol.turn_angle_min_deg:
            problem = ("wrong_axis", say.wrong_axis(axis, got, retry))
        elif abs(a) < tol.turn_angle_min_deg:
            problem = ("turn_incomplete", say.turn_incomplete(axis, a, retry))
        elif abs(a) > tol.turn_angle_max_deg:
            problem = ("turn_too_far", say.turn_too_far(axis, a, retry))
        elif off_axis > tol.off_axis_max_fraction * abs(a):
            problem = ("wrong_axis", say.not_one_axis(axis, off_axis, retry))
        elif gravity is not None and gravity > tol.gravity_closure_max_deg:
            problem = ("turn_incomplete", say.not_back(axis, gravity, retry))
        if problem is not None:
            self._turn_failed(*problem)
            return
        flags = tuple(f for f in st.flags if f not in ("saturated", "counter_gap"))
        self.turns[axis] = TurnRecord(axis, st.start, st.end, st.start_s, st.end_s, angles, flags, self._rest_before_s, gravity)
        self._live["still_s"] = 0.0
        nxt = AXES[self._axis_i + 1] if self._axis_i < 2 else None
        self._set_phase("pause", say.pause_prompt(axis, nxt))

    def _turn_failed(self, code: str, message: str) -> None:
        if self.retry_allowed:
            self.attempt += 1
            self._warn(code, message)
            self._set_phase("settle", say.PROMPTS["settle"])
            self._resume_phase = "ready"
        else:
            self.fail(code, message)

    def _check_time_limits(self) -> None:
        """Protocol time limits, in device time (so they scale with a simulated device's speed)."""
        if self.finished:
            return
        waited = self._t_now - self._phase_since_t
        tm = self.timings
        if self.state == "still" or self.phase == "settle":
            if waited > tm.fail_after_s:
                self.fail("not_still", say.not_still(tm.initial_still_s, tm.fail_after_s))
            elif waited > tm.hint_after_s and not self._hinted:
                self._hinted = True
                self._warn("hint", say.not_still_hint(tm.initial_still_s if self.state == "still" else tm.settle_s))
        elif self.phase == "ready":
            axis = AXES[self._axis_i]
            if waited > tm.fail_after_s:
                self.fail("no_motion", say.no_motion(axis, tm.fail_after_s))
            elif waited > tm.hint_after_s and not self._hinted:
                self._hinted = True
                self._warn("hint", say.no_motion_hint(axis))
        elif self.phase == "turning":
            if waited > tm.max_turn_s:
                self._turn_failed("turn_too_long", say.turn_too_long(AXES[self._axis_i], tm.max_turn_s, self.retry_allowed))
        elif self.phase == "pause":
            # a pause that never completes because the device keeps drifting ends like a missed turn
            if waited > tm.fail_after_s:
                self.fail("moved_during_pause", say.moved_during_pause(AXES[self._axis_i], tm.pause_s, False, True))


def _dedupe(stages: list[Stage]) -> list[Stage]:
    seen: set[tuple[int, int]] = set()
    out = []
    for s in stages:
        key = (s.start, s.end)
        if key not in seen:
            seen.add(key)
            out.append(s)
    return out


def _default_tracker(fs: float, full_scale_dps: float | None) -> Any:
    from calib.stages import StageTracker

    return StageTracker(fs, full_scale_dps=full_scale_dps)


