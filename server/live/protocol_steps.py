"""The protocol's steps as a guided session takes them: the live reading of each moment, a rest long enough to go
on, a stage the detector closed, a motion that starts a turn (or only a fidget), and the protocol's time limits."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from calib.stages.stage import AXES

from ..config import Settings
from . import guidance as say
from .codes import TURN_STATES, Phase, State
from .snapshot_schema import LiveReading
from .time_limits import overdue, time_left
from .turn_checks import TurnChecks
from .turn_watch import RESUME_DPS, STOP_DPS, STOP_WINDOW_S

TURN_LOOKBACK_S = 1.5  # the detector says a motion started up to this late: the turn is looked at from this far back


class ProtocolSteps(TurnChecks):
    """What moves a guided session from one step of the protocol to the next (``GuidedSession`` holds the state)."""

    settings: Settings
    clock: Callable[[], float]
    t_now: float
    _last_live_emit: float
    _phase_since_t: float
    _hinted: bool
    _calm_since: float | None  # device time of the first still sample, by the fast stop reading (turn_watch)
    _left_said_t = -1e9  # device time the time left for an overdue turn was last sent
    _moving_said = False  # whether the live reading last sent said the device was moving

    @property
    def finished(self) -> bool:
        raise NotImplementedError

    @property
    def axis(self) -> str | None:
        raise NotImplementedError

    def _emit(self, event: str) -> None: ...

    def _shown_rest(self, still_s: float, moving: bool, rate: float) -> tuple[float, bool]:
        """The rest as the page shows it: counted from the first still sample. The stage detector, which decides the
        protocol's steps, learns of a rest 1-1.4 s late (its window is centred); the ring would stay full, then jump.
        The fast reading ``rate`` of the last ``STOP_WINDOW_S`` (the one that says "hold it still") starts the count,
        and stops it as soon as the device moves."""
        if rate > RESUME_DPS:  # moving now, whatever the detector has decided yet
            self._calm_since = None
            return 0.0, True
        if rate < STOP_DPS and self._calm_since is None:
            # the session's first rest counts from its first calm reading: the link's first readings arrive at once,
            # and the device lay still from the first of them, not from the window that saw it
            calm = self.stream.calm_since() if self.stream.last_still is None else None
            self._calm_since = self.t_now - STOP_WINDOW_S if calm is None else min(calm, self.t_now - STOP_WINDOW_S)
        if self._calm_since is None:
            return still_s, moving
        return max(still_s, self.t_now - self._calm_since), False

    def still_target(self) -> float | None:
        """How long the device must rest in the current state or phase (s), None when no rest is asked for."""
        if self.state == State.STILL:
            return self.timings.initial_still_s
        if self.phase in (Phase.PAUSE, Phase.PLACING, Phase.CHECKING):
            return self.timings.pause_s
        if self.phase == Phase.SETTLE:
            return self.timings.settle_s
        return None

    def time_left_s(self) -> float | None:
        """How long (device s) the session still waits for the turn or rest it asks for before it ends for want of it
        (``server.live.time_limits``); None in a phase with no such limit."""
        if self.finished:
            return None
        return time_left(self.state, self.phase, self.axis, self.t_now - self._phase_since_t, self.timings)

    def _update_live(self) -> None:
        still_s, moving, raw = self.stream.live()
        angle = self.live_angle.of(raw)
        rate = self.stream.recent_rate(STOP_WINDOW_S)  # the fast reading: the ring's count and the turn's stop
        shown_still, shown_moving = self._shown_rest(still_s, moving, rate)
        self.live_reading = LiveReading(shown_still, shown_moving, angle.tolist(), raw.tolist())
        if self.phase in (Phase.RETURNING, Phase.TURNING, Phase.PLACING, Phase.CHECKING):
            if self._watch_turn(still_s, moving, raw, angle, rate):
                return
        elif self.phase == Phase.PAUSE and self._watch_pause(moving, angle):
            return

        target = self.still_target()
        if target is not None and still_s >= target:
            self._still_reached()
            return
        now = self.clock()
        # the device starting or ceasing to move in a counted rest is sent at once, as a state change is: a service
        # catching up in a burst would otherwise read a whole knock between two of its few snapshots a second, and the
        # ring would never show it
        flipped = target is not None and shown_moving != self._moving_said
        if flipped or now - self._last_live_emit >= 1.0 / self.settings.sse_rate_hz:
            if self.phase in (Phase.TURNING, Phase.PLACING):
                self._last_live_emit, self._moving_said = now, shown_moving
                self._emit("angle")
            elif target is not None:
                self._last_live_emit, self._moving_said = now, shown_moving
                self._emit("progress")
            elif self._hinted and self.phase == Phase.READY and self.kit_id is None and self.t_now - self._left_said_t >= 1.0:
                # once the turn is overdue, the time left for it, once a second of device time (a kit's page has its own)
                self._last_live_emit, self._left_said_t = now, self.t_now
                self._emit("progress")

    def _still_reached(self) -> None:
        if self.state == State.STILL:
            self._axis_i = 0
            self._set_state(State.TURN_X, Phase.READY, say.turn_prompt("x"))
            return
        axis = AXES[self._axis_i]
        if self.phase == Phase.SETTLE:
            resume = self._resume_phase
            self._resume_phase = Phase.READY
            if resume == Phase.PAUSE:
                self._set_phase(Phase.PAUSE, say.pause_prompt(axis, self._next_axis()))
            else:
                self._set_phase(Phase.READY, say.turn_prompt(axis))
            return
        if self.phase == Phase.PAUSE and self._early is None:
            nxt = self._next_axis()
            if self._redo:
                self._redo.pop(0)
            if nxt is not None:
                self._axis_i = AXES.index(nxt)
                self.attempt = 1
                self._set_state(TURN_STATES[nxt], Phase.READY, say.turn_prompt(nxt))
            else:
                self._set_state(State.COMPUTING, None, say.PROMPTS["computing"])

    def _on_event(self, ev: Any) -> None:
        kind = getattr(ev, "kind", None)
        if kind == "stage_closed":
            st = self.stream.globalise(ev.stage)
            if st.kind == "still":
                self.stream.closed_still(st)
            elif self.phase in (Phase.RETURNING, Phase.TURNING, Phase.PLACING, Phase.CHECKING):
                self._check_turn(st)
            elif self.phase == Phase.PAUSE and self._early is not None:
                self._early = None  # a bump that never became a turn: the pause's count starts again
                self._moved(st.start_s)
            return
        if kind == "motion_started":
            self._on_motion(float(getattr(ev, "t", self.t_now)))

    def _begin_turn(self, rest_before_s: float, provisional: str | None) -> None:
        self._provisional = provisional
        self._rest_before_s = rest_before_s
        self._turn_lost = 0
        self._turn_refused = 0
        self._turn_since_t = self.t_now - TURN_LOOKBACK_S

    def _on_motion(self, t_motion: float) -> None:
        still_s = self.stream.rest_before(t_motion)
        if self.state == State.STILL:
            if still_s >= self.timings.min_rest_before_turn_s:
                # Started before the countdown ended but after enough rest: take it as the x turn if
                # it proves to be one; a mere fidget just restarts the count.
                self._begin_turn(still_s, "initial")
                self._axis_i = 0
                self._set_state(State.TURN_X, Phase.TURNING, say.turning_prompt("x"))
                return
            if still_s > 0.2 * self.timings.initial_still_s:
                self._moved(t_motion)
            self.live_reading.still_s = 0.0
            return
        if self.state not in TURN_STATES.values():
            return
        axis = AXES[self._axis_i]
        if self.phase == Phase.READY:
            self._begin_turn(still_s, None)
            # asked again: the first motion may be the device put back (a kit's tray is put back as its prompts say)
            if self._off_place_deg is not None and self.kit_id is None:
                self._set_phase(Phase.RETURNING, say.returning_prompt(axis))
            else:
                self._set_phase(Phase.TURNING, say.turning_prompt(axis))
        elif self.phase == Phase.PAUSE:
            # a bump (the count starts again) or the next turn started before the count ended: told apart
            # by how far it turns (_watch_pause)
            self._early = still_s

    def wait_with_kit(self) -> None:
        """The kit waits for a wearable whose link was lost, the tray held still as its prompt says: this one's time
        limits count from now (a turn not started meanwhile is the kit's wait, not the clinician's miss)."""
        if not self.finished:
            self._phase_since_t = self.t_now

    def _check_time_limits(self) -> None:
        """Protocol time limits, in device time (so they scale with a simulated device's speed)."""
        if self.finished:
            return
        late = overdue(self.state, self.phase, self.axis, self.t_now - self._phase_since_t, self._hinted, self.timings,
                       self.retry_allowed)
        if late is None:
            return
        if late.action == "hint":
            self._hinted = True
            self._warn("hint", late.message)
        elif late.action == "retry" and late.code is not None:
            self._turn_failed(late.code, late.message)
        elif late.code is not None:
            self.fail(late.code, late.message)
