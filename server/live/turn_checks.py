"""How a guided session checks each turn: when its motion stops, when it has rested long enough to be checked,
what a move in the pause after it means, and what a failed check leads to (a try again or the end). A wearable turned
in a kit's tray holds its fault for the kit to judge (``HeldFault``): the tray is turned again only when every
wearable at that turn saw one.

``TurnChecks`` is a part of ``GuidedSession`` (server.live.session), which keeps the states, the link and the
outcome; the fields and methods declared here without a body are the session's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.judge.acceptance import Tolerances
from calib.stages.stage import AXES, Stage

from ..config import ProtocolTimings
from . import guidance as say
from . import kit_guidance as kit_say
from .codes import TURN_STATES, EndReason, Phase, State
from .snapshot_schema import LiveReading, SessionWarning
from .stream import SessionStream
from .turn_judge import TurnMeasure, is_no_turn, judge_turn
from .turn_watch import EARLY_TURN_DEG, RESUME_DPS, STOP_DPS, LiveAngle
from .turns import TurnRecord


def off_place_deg(angles: np.ndarray) -> float:
    """How far a motion that swept ``angles`` (3,) deg (raw: up to a scale factor's error) left the device from where
    it started: each axis's angle from the nearest whole turn, the largest (a turn stopped at 296 deg leaves it 64 deg
    off; a full turn, in its place)."""
    rest = np.abs(np.asarray(angles, dtype=float)) % 360.0
    return float(np.max(np.minimum(rest, 360.0 - rest)))


@dataclass(frozen=True)
class HeldFault:
    """A fault a kit's wearable saw in a turn or its pause, held until the kit judges whose it is (its own, or the tray's)."""

    code: EndReason
    message: str
    resume: Phase  # what a try again leads to: the turn again (ready) or only its pause
    at_t: float  # the wearable's device time when it saw it, s


@dataclass(frozen=True)
class HeldMove:
    """A kit's wearable moved while resting (its count starts again), held until the kit knows whether the tray moved
    or only this wearable."""

    at_t: float  # the wearable's device time when the move began, s
    seen_t: float  # ... and when it was seen for what it is (a bump: once it ended), s


class TurnChecks:
    """The turn phases of a guided session: turning, placing, the check, the pause and retries."""

    device_id: str
    kit_id: str | None
    held_fault: HeldFault | None
    held_move: HeldMove | None
    moves: list[float]  # the device time of each move seen while resting, s
    kit_closed: set[str]  # the turns (axes) whose fault, this wearable's own, its kit closed with the others' readings
    warnings: list[SessionWarning]
    t_now: float
    state: State
    phase: Phase | None
    attempt: int
    turns: dict[str, TurnRecord]
    stream: SessionStream
    tol: Tolerances
    timings: ProtocolTimings
    live_angle: LiveAngle
    live_reading: LiveReading
    _axis_i: int
    _provisional: str | None
    _early: float | None
    _redo: list[str]
    _redone: set[str]  # turns already asked again after a result: a second failure is the sensor's
    _redone_for: set[tuple[str, str | None]]  # ... and the failed checks they were asked again for
    _turn_lost: int
    _turn_refused: int
    _resume_phase: Phase
    _rest_before_s: float
    _turn_since_t: float  # device time from which the turn in progress is looked at (its start, with margin)
    _off_place_deg: float | None  # after a turn asked again, how far it left the device from its place; None: not asked again

    @property
    def retry_allowed(self) -> bool:
        raise NotImplementedError

    @property
    def finished(self) -> bool:
        raise NotImplementedError

    @property
    def full_scale(self) -> float | None:
        raise NotImplementedError

    def fail(self, code: EndReason | str, message: str) -> None: ...

    def _set_phase(self, phase: Phase | None, prompt: str, event: str = "prompt", keep_clock: bool = False) -> None: ...

    def _set_state(self, state: State, phase: Phase | None, prompt: str) -> None: ...

    def _warn(self, code: str, message: str, emit: bool = True) -> None: ...

    def _begin_turn(self, rest_before_s: float, provisional: str | None) -> None: ...

    def _watch_turn(self, still_s: float, moving: bool, raw: np.ndarray, angle: np.ndarray, rate: float) -> bool:
        """The turn in progress: say "hold still" the moment it stops (``rate``: the largest rate of the last
        ``STOP_WINDOW_S``), "checking" once it rests after what looks like a full turn. True when the session moved
        on. A turn counts only when the stage detector closes it (its closing rest is complete): until then the page
        says "checking", and a move spoils the turn, so the clinician is told one thing, once."""
        axis = AXES[self._axis_i]
        k = AXES.index(axis)
        if self.phase == Phase.CHECKING:
            if self.held_fault is not None:
                return False  # the kit judges the fault already seen; the motion that goes on with it adds nothing
            if moving:
                # back at rest after a full turn, then moved again before the rest was long enough to
                # close the turn: the turn and that motion cannot be told apart any more
                self._moved_during_pause(axis)
                return True
            return False
        if self.phase == Phase.RETURNING:
            # the device put back in its place sweeps about as far as it was off; a motion well beyond that is the turn
            if float(np.abs(raw).max()) >= (self._off_place_deg or 0.0) + EARLY_TURN_DEG:
                self._set_phase(Phase.TURNING, say.turning_prompt(axis), keep_clock=True)
            return False
        if self.phase == Phase.TURNING:
            if rate < STOP_DPS and float(np.abs(raw).max()) >= EARLY_TURN_DEG:
                took = None if self._turn_lost or self._turn_refused else self.stream.clipped_motion(self._turn_since_t)
                if took is not None:
                    # too fast is known the moment the turn stops: said now, not once its closing rest is complete
                    # (the stage then closes in the settle and is not checked again)
                    self._provisional = None
                    self._off_place_deg = 0.0
                    self._turn_failed(EndReason.TOO_FAST, say.too_fast(axis, self.full_scale, self.retry_allowed, took))
                    return True
                if self.live_angle.near_full(float(angle[k])):
                    self._set_phase(Phase.PLACING, say.placing_prompt(axis, self.live_angle.calibrated), keep_clock=True)
        elif rate > RESUME_DPS:
            self._set_phase(Phase.TURNING, say.turning_prompt(axis), keep_clock=True)
        elif not moving and still_s >= self.timings.rest_seen_s and abs(raw[k]) >= self.tol.turn_angle_min_deg:
            self._set_phase(Phase.CHECKING, say.checking_prompt(axis), keep_clock=True)
        return False

    def _measure(self, axis: str, st: Stage, angles: np.ndarray, lost: int, refused: int = 0) -> TurnMeasure:
        """What the checks of a turn about ``axis`` over ``st`` read (``angles``: its raw swept angles)."""
        true_angle = None
        if self.live_angle.calibrated and self.live_angle.checks_turns:
            true_angle = float(self.live_angle.of(angles)[AXES.index(axis)])
        return TurnMeasure(angles, self.stream.saturated(st), lost, self.stream.gravity_change_deg(st), true_angle,
                           duration_s=st.end_s - st.start_s, refused=refused)

    def _record_turn(self, axis: str, st: Stage, angles: np.ndarray, gravity_deg: float | None) -> None:
        self.turns[axis] = TurnRecord(axis, st.start, st.end, st.start_s, st.end_s, angles,
                                      tuple(f for f in st.flags if f not in ("saturated", "counter_gap")), self._rest_before_s, gravity_deg)
        self._early = None
        nxt = self._next_axis()
        self._set_phase(Phase.PAUSE, say.pause_prompt(axis, nxt))

    def _next_axis(self) -> str | None:
        """The turn asked after the current one: the next in protocol order, or the next turn to redo (None: compute)."""
        if self._redo:
            return self._redo[1] if len(self._redo) > 1 else None
        return AXES[self._axis_i + 1] if self._axis_i < 2 else None

    def _watch_pause(self, moving: bool, angle: np.ndarray) -> bool:
        """A motion in the pause after a recorded turn: a bump that restarts the count, or the next turn started
        early once it has turned far enough."""
        if self._early is not None and not self._redo and self._axis_i < 2 and float(np.abs(angle).max()) >= EARLY_TURN_DEG:
            rest, self._early = self._early, None
            self._begin_turn(rest, "pause")
            self._axis_i += 1
            self.attempt = 1
            nxt = AXES[self._axis_i]
            self._set_state(TURN_STATES[nxt], Phase.TURNING, say.turning_prompt(nxt))
            return True
        return False

    def _moved_during_pause(self, axis: str) -> None:
        self.moves.append(self.t_now)
        recorded = self.phase == Phase.PAUSE and axis in self.turns
        msg = say.moved_during_pause(axis, self.timings.pause_s, self.retry_allowed, recorded)
        # a recorded turn keeps its place and only the pause is done again; otherwise the turn is asked again
        self._fault(EndReason.MOVED_DURING_PAUSE, msg, Phase.PAUSE if recorded else Phase.READY)

    def _fault(self, code: EndReason, message: str, resume: Phase) -> None:
        """A fault in a turn or its pause: asked again (or the end, with no try left); in a kit, held for the kit."""
        if self.kit_id is not None:
            self.held_fault = HeldFault(code, message, resume, self.t_now)
            self._set_phase(Phase.CHECKING, say.checking_prompt(AXES[self._axis_i]), keep_clock=True)
            return
        self._ask_again(code, message, resume)

    def _ask_again(self, code: EndReason, message: str, resume: Phase) -> None:
        if self.retry_allowed:
            self.attempt += 1
            self._warn(code, message)
            self._set_phase(Phase.SETTLE, say.PROMPTS["settle"])
            self._resume_phase = resume
        else:
            self.fail(code, message)

    def _moved(self, at_t: float | None = None) -> None:
        """The device moved while resting (at its device time ``at_t``, default now): the count starts again. In a kit
        the warning waits for the kit's judgement (server.live.kit_faults): the tray moved, or only this wearable."""
        self.moves.append(self.t_now if at_t is None else float(at_t))
        if self.kit_id is None:
            self._warn("moved", say.MOVED_RESTART)
        elif self.held_move is None:
            self.held_move = HeldMove(self.moves[-1], self.t_now)

    def say_move(self, alone_of: list[str] | None) -> None:
        """The kit judged the held move: the tray's (``alone_of`` None), or this wearable's alone, the rest of the kit
        (``alone_of``) resting still meanwhile."""
        self.held_move = None
        if self.finished:
            return
        if alone_of is None:
            self._warn("moved", say.MOVED_RESTART)
        else:
            self._warn("kit_moved_alone", kit_say.kit_moved_alone(self.device_id, None, alone_of))

    def release_held(self) -> None:
        """The kit judged the held fault the tray's (every wearable at that turn saw one): asked again, as alone."""
        held, self.held_fault = self.held_fault, None
        if held is not None and not self.finished:
            self._ask_again(held.code, held.message, held.resume)

    def kit_closes_turn(self, passed: list[str], moved_alone: bool) -> None:
        """The kit judged the held fault this wearable's own: the tray is not turned again for it, and the kit's
        calibration closes that turn from the others' readings of it. ``passed``: the wearables that passed that turn,
        or with ``moved_alone`` that rested still while this one moved."""
        held, self.held_fault = self.held_fault, None
        if held is None or self.finished:
            return
        axis = AXES[self._axis_i]
        self.kit_closed.add(axis)
        if moved_alone:
            said = kit_say.kit_moved_alone(self.device_id, axis, passed)
        elif held.code == EndReason.MOVED_DURING_PAUSE:
            said = kit_say.kit_tray_moved_unchecked(self.device_id, axis, passed)
        elif held.code == EndReason.TOO_FAST:  # its range, not the hand: the others read that turn whole
            said = kit_say.kit_clipped_turn(self.device_id, axis, self.full_scale, passed)
        else:
            said = kit_say.kit_closed_turn(self.device_id, held.message, passed)
        self._warn("kit_moved_alone" if moved_alone else "kit_closed_turn", said)
        self._early = None
        self._set_phase(Phase.PAUSE, say.pause_prompt(axis, self._next_axis()))

    def kit_not_turned(self, turned: list[str]) -> None:
        """The rest of the kit (``turned``) turned about this wearable's axis and its readings show none of it (not in
        the tray, or not switched on): said once, and that turn is closed by the kit, so that this wearable follows the
        tray's steps (the kit's calibration leaves it out if it never follows the others: calib.kit.together)."""
        if self.finished or self.phase != Phase.READY:
            return
        axis = AXES[self._axis_i]
        if not any(w.code == "kit_not_turned" for w in self.warnings):
            self._warn("kit_not_turned", kit_say.kit_not_turned(self.device_id, axis, turned))
        self.kit_closed.add(axis)
        self._set_phase(Phase.PAUSE, say.pause_prompt(axis, self._next_axis()))

    def turn_again_with_kit(self, axes: list[str], message: str) -> None:
        """Its kit's calibration asks the tray these turns again (server.live.kit_redo): asked as a result's turns are
        alone, in the kit's words (``message``, said once of the tray)."""
        if self.finished or self.state != State.COMPUTING:
            return
        # a scale factor out of range again after the tray's turn was made again is the sensor's, as alone
        self._redone_for.update(("k", a) for a in axes)
        self._redo_turns(axes, message, code="kit_turn_again")

    def _redo_turns(self, axes: list[str], message: str, code: str = EndReason.OUT_OF_TOLERANCE) -> None:
        """The result is out of range on scale factors only: most likely those turns were not full ones. Ask them
        again in this session (the others stand), once each; then compute again."""
        self._redone.update(axes)
        self.kit_closed.difference_update(axes)
        self._redo = list(axes)
        # the device rests where the last turn left it: off its place if that turn (one asked again) stopped short
        last = max(self.turns.values(), key=lambda r: r.end_s, default=None)
        self._off_place_deg = 0.0 if last is None else off_place_deg(last.angle_deg)
        for a in axes:
            self.turns.pop(a, None)
        self._axis_i = AXES.index(axes[0])
        self.attempt += 1
        self._warn(code, message, emit=False)
        self._set_state(TURN_STATES[axes[0]], Phase.SETTLE, say.PROMPTS["settle"])
        self._resume_phase = Phase.READY

    def _undo_early_motion(self) -> None:
        """An early motion (before a countdown ended) that was no turn at all."""
        provisional, self._provisional = self._provisional, None
        if provisional == "initial":
            self._moved()
            self._axis_i = 0
            self._set_state(State.STILL, Phase.WAITING, say.PROMPTS["still"])
        else:
            # the turn before was confirmed and stays; its pause is counted again
            self._axis_i -= 1
            axis = AXES[self._axis_i]
            self.state = TURN_STATES[axis]
            self._moved()
            self._set_phase(Phase.PAUSE, say.pause_prompt(axis, self._next_axis()))

    def _check_turn(self, st: Stage) -> None:
        if self.held_fault is not None:
            return  # the kit judges the fault this wearable saw first
        axis = AXES[self._axis_i]
        angles = self.stream.turn_angles(st)
        if is_no_turn(angles, self.tol):
            if self._provisional is not None:
                self._undo_early_motion()
            else:
                # the device pushed back against the block, not a turn: no try is used, the same turn is still asked
                self._off_place_deg = None  # back in its place: the next motion is the turn
                self._set_phase(Phase.READY, say.turn_prompt(axis), keep_clock=True)
            return
        self._provisional = None
        if self.stream.rest_after_full_turn(st, AXES.index(axis), self.timings.rest_seen_s, self.tol.turn_angle_min_deg):
            # back at rest after a full turn, then moved again before the rest was long enough to close
            # the turn (the stage detector merged the two): the turn cannot be used
            self._moved_during_pause(axis)
            return
        lost, refused = self._turn_lost, self._turn_refused
        if not lost and not refused and "counter_gap" in st.flags:  # a gap in the motion before the turn was confirmed
            lost = max(1, self.stream.missing_samples(st))
        measure = self._measure(axis, st, angles, lost, refused)
        problem = judge_turn(axis, measure, self.tol, self.full_scale, self.retry_allowed)
        self._off_place_deg = off_place_deg(angles) if problem is not None else None
        if problem is not None:
            self._turn_failed(*problem)
            return
        self._record_turn(axis, st, angles, measure.gravity_deg)

    def _turn_failed(self, code: EndReason, message: str) -> None:
        self._fault(code, message, Phase.READY)
