"""The guided calibration session: a state machine fed by the streaming stage detector.

States (in protocol order): connecting -> still -> turn_x -> turn_y -> turn_z -> computing -> done,
with reconnecting while the link is down, and the end states done, failed, cancelled. Turn states
have phases: settle (rest again after a reconnection or a retry), ready (prompting the turn),
turning (live angle), placing (the motion stopped: rest in place), pause (rest after the checked turn).
A turn is checked as soon as the device has rested ``rest_seen_s`` after it, and confirmed when the
stage detector closes it; moving before that asks for the turn again, moving after only restarts the
pause's count. Every change is reported to a listener
as a full snapshot; the listener (server.events) numbers them and streams them as SSE.

The machine is synchronous and knows no I/O: the runner (server.live.runner) feeds it sample batches,
link events and clock ticks, and runs the estimator when the state reaches computing. The samples and
the stage detector live in a ``SessionStream``; whether a closed motion is the turn asked for is
``turn_judge``'s verdict, and the time limits are ``time_limits``'.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

import numpy as np

from calib.judge.judgement import Judgement, judge
from calib.recording import Recording, RecordingMeta
from calib.result import CalibrationResult
from calib.stages.stage import AXES, Stage

from ..config import Settings
from . import firmware_guidance as firmware_says
from . import guidance as say
from .buffer import SampleBuffer
from .codes import END_STATES, TURN_STATES, EndReason, Phase, State
from .history import FailedChecks
from .lateness import Lateness
from .protocol_steps import ProtocolSteps
from .sensor_faults import SensorFaultWatch
from .snapshot import session_snapshot
from .snapshot_schema import CausedBy, LiveReading, SessionOut, SessionWarning
from .stream import SessionStream, TrackerFactory
from .turn_checks import HeldFault, HeldMove
from .turn_watch import LiveAngle
from .turns import TurnRecord

Listener = Callable[[str, SessionOut], None]


def _utc() -> str:
    return datetime.now(UTC).isoformat()


class GuidedSession(ProtocolSteps, Lateness):
    """One guided calibration of one device."""

    def __init__(
        self,
        session_id: str,
        device_id: str,
        settings: Settings,
        tracker_factory: TrackerFactory | None = None,
        listener: Listener | None = None,
        max_attempts: int | None = None,
        method: str | None = None,
        clock: Callable[[], float] = time.monotonic,
        live_angle: LiveAngle | None = None,
    ) -> None:
        self.id = session_id
        self.device_id = device_id
        self.settings = settings
        self.timings = settings.timings
        self.tol = settings.tolerances
        self.method = method or settings.method
        self.heading_prior_deg = settings.heading_prior_deg  # the site's stated heading spread, if any (closure)
        self.max_attempts = max(1, int(max_attempts or settings.max_turn_attempts))
        self.listener = listener
        self.clock = clock
        self.live_angle = live_angle or LiveAngle()  # the accepted calibration's K for the live angle, if any

        self.state: State = State.CONNECTING
        self.phase: Phase | None = None
        self.prompt = say.PROMPTS["connecting"]
        self.started_at = _utc()
        self.started_mono = clock()
        self.ended_at: str | None = None
        self.reason_code: EndReason | None = None
        self.reason: str | None = None
        self.warnings: list[SessionWarning] = []
        self.result: CalibrationResult | None = None
        self.passed: bool | None = None
        self.judgement: Judgement | None = None  # the result's checks, departures and accuracy (calib.judge)
        self.decision: str | None = None
        self.calibration_id: int | None = None
        self.attempt = 1
        self.device_info: dict[str, Any] = {}

        self.stream = SessionStream(tracker_factory)
        self._faults = SensorFaultWatch()  # readings no working sensor gives at rest
        self.fs_estimate: float | None = None  # the link's estimate of the true rate from device time
        self.fs_rel_std: float | None = None  # ... its relative standard error, when it comes from arrival times
        self._clock_from_next = True  # the current phase's time limit counts from the next sample received
        self.lost_samples = 0  # on the radio link
        self.refused_samples = 0  # in packets the wearable sent malformed (the link refused them)

        self.turns: dict[str, TurnRecord] = {}
        self._axis_i = 0
        self._phase_since_t = 0.0
        self._hinted = False
        self._turn_lost = self._turn_refused = 0
        self._resume: tuple[State, Phase | None] | None = None
        self._resume_phase = Phase.READY  # what a settle phase leads to: the turn again, or the pause
        self._off_place_deg: float | None = None  # how far a turn asked again left the device from its place
        self._turn_since_t = 0.0  # device time from which the turn in progress is looked at
        self._provisional: str | None = None  # a turn started before the countdown ended: "initial" | "pause"
        self._rest_before_s = 0.0
        self._redo: list[str] = []  # turns asked again after the result (the one being redone first)
        self._redone: set[str] = set()  # turns already asked again after a result: a second failure is the sensor's
        self._redone_for: set[tuple[str, str | None]] = set()  # ... and the failed checks they were asked again for
        self._early: float | None = None  # a motion in a confirmed pause, with the rest before it: a bump or the next turn
        self._link_lost_mono: float | None = None
        self._silent_since: float | None = None  # the watchdog's clock when the data stopped (the link still up)
        self.service_late_s = 0.0  # how long the service itself did not run during this session (its own lateness)
        self._late_said_at = -1e9  # device time of the last service_late warning
        self.live_reading = LiveReading()
        self._calm_since: float | None = None
        self.t_now = 0.0
        self.caused_by: CausedBy | None = None
        self.kit_id: str | None = None  # the kit session this wearable is turned in, with the rest of its tray
        self.held_fault: HeldFault | None = None  # a fault in a turn the kit judges (server.live.turn_checks)
        self.held_move: HeldMove | None = None
        self.moves: list[float] = []
        self.kit_closed: set[str] = set()
        self._last_live_emit = -1e9
        self.snapshot_count = 0
        self._emitted_state: str | None = None

    # -- public properties ------------------------------------------------------------------------
    @property
    def buf(self) -> SampleBuffer:
        """Every sample received so far."""
        return self.stream.buf

    @property
    def fs(self) -> float | None:
        return self.stream.fs

    @property
    def full_scale(self) -> float | None:
        return self.stream.full_scale

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
        self.device_info = dict(info or {})
        self.stream.start(fs, full_scale_dps)
        self._set_state(State.STILL, Phase.WAITING, say.PROMPTS["still"])

    def feed(
        self,
        t: np.ndarray,
        gyro: np.ndarray,
        accel: np.ndarray | None = None,
        seq: np.ndarray | None = None,
        lost_before: int = 0,
        received_at: float | None = None,
        link_clock: float | None = None,
        refused_before: int = 0,
    ) -> None:
        """One batch of samples (device time t in s, raw gyro in deg/s, accel in g), received at ``received_at`` (Unix
        time, s; None: now) and ``link_clock`` on the link's clock (s, on a simulated wearable's time scale; None: the
        Unix time). ``lost_before`` samples before it were lost on the radio, ``refused_before`` came in packets the
        link refused as malformed."""
        if self.finished or self.state in (State.RECONNECTING, State.CONNECTING) or self.stream.tracker is None:
            return
        if self.state == State.COMPUTING:
            self._keep(t, gyro, accel, seq)
            self.lost_samples += int(lost_before)
            self.refused_samples += int(refused_before)
            return
        first = self.buf.n == 0
        times = self.stream.receive(t, gyro, accel, seq)
        if times is None:
            return
        t = times
        if self.still_target() is not None and (fault := self._faults.check(self.buf, self.full_scale)):
            self.fail(EndReason.SENSOR_FAULT, say.sensor_fault(fault))  # a sensor no rest can satisfy: not the hands
            return
        received = received_at if received_at is not None else time.time()
        self.stream.arrived(float(t[-1]), received if link_clock is None else link_clock)
        if link_clock is not None and (ahead := self.stream.clock_ahead(self.service_late_s)) is not None:
            self.fail(EndReason.DEVICE_CLOCK, firmware_says.device_clock_ahead(*ahead, self.device_info.get("firmware")))
            return
        self.caused_by = CausedBy(t_device_s=float(t[-1]), received_at=received)
        if first:  # samples missing before the first are not this session's (the time between two sessions on one link)
            lost_before = refused_before = 0
        if self._clock_from_next:
            # A device's clock does not start at 0 (it keeps running between sessions) and runs on while
            # the link is down: the time limits count from the session's first sample, and after a
            # reconnection from the first sample that came back.
            self._clock_from_next = False
            self._phase_since_t = float(t[0])
        self.lost_samples += int(lost_before)
        self.refused_samples += int(refused_before)
        if self.phase == Phase.TURNING:
            self._turn_lost += int(lost_before)
            self._turn_refused += int(refused_before)
        self.t_now = float(t[-1])
        try:
            for ev in self.stream.detect():
                self._on_event(ev)
                if self.finished or self.state == State.COMPUTING:
                    return
            self._update_live()
            self._check_time_limits()
        finally:
            # only what this batch causes carries it; later snapshots (result, decision) do not
            self.caused_by = None

    def _keep(self, t: np.ndarray, gyro: np.ndarray, accel: np.ndarray | None, seq: np.ndarray | None) -> None:
        """Samples that arrive while the result is computed: recorded and followed by the stage detector (a turn may
        be asked again), nothing else."""
        times = self.stream.receive(t, gyro, accel, seq)
        if times is None:
            return
        self.t_now = float(times[-1])
        for ev in self.stream.detect():
            self._on_event(ev)  # in computing only the rests are kept

    def link_lost(self) -> None:
        """The radio link dropped: pause; the current turn is redone after reconnection."""
        if self.finished or self.state in (State.COMPUTING, State.RECONNECTING, State.CONNECTING):
            return
        self._early = None
        self.held_fault = self.held_move = None  # the turn is redone after reconnection: the kit judges nothing of it
        self._resume = (self.state, self.phase)
        self._link_lost_mono = self.clock()
        self._warn("link_lost", say.PROMPTS["reconnecting"])
        self._set_state(State.RECONNECTING, None, say.PROMPTS["reconnecting"])

    def link_restored(self) -> None:
        """The link is back: rest again, then redo the step that was interrupted."""
        if self.state != State.RECONNECTING or self._resume is None:
            return
        state, phase = self._resume
        self._resume = None
        self._link_lost_mono = None
        self._clock_from_next = True  # the device's clock ran on while the link was down
        # the tracker carries on across the gap (its noise floor stays valid); the interrupted motion
        # closes with a counter_gap flag while the session waits for rest and is not used
        if state == State.STILL:
            self._set_state(State.STILL, Phase.WAITING, say.PROMPTS["still"])
            return
        # after a pause the turn was recorded already and only the pause is done again
        self._warn("link_restored", say.link_restored(None if phase == Phase.PAUSE else AXES[self._axis_i]))
        self._set_state(state, Phase.SETTLE, say.PROMPTS["settle"])
        self._resume_phase = Phase.PAUSE if phase == Phase.PAUSE else Phase.READY

    def tick(self) -> None:
        """Wall-clock checks: the reconnection limit and the overall watchdog."""
        if self.finished:
            return
        now = self.clock()
        if self.state == State.RECONNECTING and self._link_lost_mono is not None:
            if now - self._link_lost_mono > self.settings.reconnect_timeout_s:
                self.fail(EndReason.LINK_LOST, say.link_lost(self.settings.reconnect_timeout_s))
                return
        if self._silent_since is not None and now - self._silent_since > self.settings.reconnect_timeout_s:
            self.fail(EndReason.LINK_LOST, say.link_lost(self.settings.reconnect_timeout_s))
            return
        if now - self.started_mono > self.settings.session_timeout_s:
            self.fail(EndReason.TIMEOUT, say.timeout(self.settings.session_timeout_s))

    def cancel(self, reason: str = "Cancelled by the operator.") -> bool:
        if self.finished:
            return False
        self.reason_code = EndReason.CANCELLED
        self.reason = reason
        self._end(State.CANCELLED, reason)
        return True

    def fail(self, code: EndReason | str, message: str) -> None:
        if self.finished:
            return
        self.reason_code = EndReason(code)
        self.reason = message
        self._end(State.FAILED, message)

    # -- computing --------------------------------------------------------------------------------
    def recording(self) -> Recording:
        """Everything received so far as a Recording (device time, raw readings)."""
        meta = RecordingMeta(sample_rate_hz=self.fs_estimate or self.fs, device_id=self.device_id, gyro_full_scale_dps=self.full_scale,
                             sensor_model=self.device_info.get("sensor_model"), source=f"session {self.id}")
        rec = self.stream.recording(meta)
        if self.device_info.get("time_stamps") == "arrival" and rec.seq is not None and self.fs_estimate:
            return rec.timed_by_counter(self.fs_estimate, self.fs_rel_std)  # the live times followed an improving rate estimate
        return rec

    def take_recording(self, message: str) -> bool:
        """Its kit's tray has been turned through the protocol: the recording so far is calibrated with the kit's,
        whatever step this wearable's own guidance is in (False when it has ended, or has no recording to give)."""
        if self.finished or self.state in (State.COMPUTING, State.CONNECTING, State.RECONNECTING):
            return False
        self.held_fault = self.held_move = None
        self._warn("kit_ahead", message)
        self._set_state(State.COMPUTING, None, say.PROMPTS["computing"])
        return True

    def protocol_stages(self) -> list[Stage]:
        """The stages the estimator gets: every still, and the turns that passed their checks."""
        return self.stream.protocol_stages(list(self.turns.values()))

    def set_result(self, result: CalibrationResult, history: list[dict[str, Any]] | None = None,
                   failed_before: FailedChecks = frozenset(), can_redo: bool = True) -> None:
        """The estimator's result: judge it against the tolerances (and the device's earlier calibrations,
        ``history``), then done, failed, or (``can_redo``: the device still streams) the turns that most likely
        were not full ones asked again (``failed_before``: the checks its last judged result failed)."""
        if self.finished:
            return
        judgement = judge(result, self.tol, history or [])
        failed = judgement.failed_checks
        redo = say.turns_to_redo(failed)
        if redo and can_redo and self.max_attempts > 1 and not self._redone.intersection(redo):
            self._redone_for.update((c.name, c.axis) for c in failed if c.axis in redo)
            self._redo_turns(redo, say.redo_turns(failed))
            return
        self.result = result
        self.judgement = judgement
        self.passed = judgement.passed
        if not self.passed:
            # a turn that failed again after it was asked again: the same axis twice, so the sensor is suspect
            again = failed_before | self._redone_for
            self.fail(EndReason.OUT_OF_TOLERANCE, say.out_of_tolerance(failed, again))
            return
        self._end(State.DONE, say.done_prompt(True))

    # -- snapshots --------------------------------------------------------------------------------
    def snapshot(self, event: str = "state") -> SessionOut:
        """The full state of the session, as every SSE event and GET /sessions/{id} carry it."""
        return session_snapshot(self, event)

    def decide(self, decision: str, calibration_id: int | None) -> None:
        """The operator accepted or discarded the result (already written to the store)."""
        self.decision = decision
        self.calibration_id = calibration_id
        self.prompt = say.decided(decision)
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

    def _set_state(self, state: State, phase: Phase | None, prompt: str) -> None:
        changed = state != self.state
        self.state = state
        self._set_phase(phase, prompt, "state" if changed else "prompt")

    def _set_phase(self, phase: Phase | None, prompt: str, event: str = "prompt", keep_clock: bool = False) -> None:
        self.phase = phase
        self.prompt = prompt
        if not keep_clock:  # turning and placing share the turn's time limit
            self._phase_since_t = self.t_now
            self._hinted = False
        self._emit(event)

    def _warn(self, code: str, message: str, emit: bool = True) -> None:
        self.warnings.append(SessionWarning(code=code, message=message, t_device_s=round(self.t_now, 3), at=_utc()))
        if emit:
            self._emit("warning")

    def _end(self, state: State, prompt: str) -> None:
        self.state = state
        self.phase = None
        self.prompt = prompt
        self.ended_at = _utc()
        self._emit("state")
