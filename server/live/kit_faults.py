"""Whose fault a kit's wearable saw in a turn or its pause: the tray's, or its own.

Turned together, the kit's wearables see one motion, but each checks it on its own readings: one with a smaller range
clips a fast turn the others read whole, one with an older calibration finds a turn short that the others find full,
one loose in its slot moves in a pause while the tray stays still. A fault is the tray's when every wearable at that
turn saw one: the tray is turned again (each wearable's own try, as alone). One the rest of the kit did not see is
that wearable's own: the tray is not turned again for it, and the kit's calibration closes that turn from the others'
readings of it. A wearable never asks a turn again alone, so it never falls behind the tray and is never failed for
a turn it judged against a step the tray had left.

A move while resting (the count starts again) is judged alike: that wearable moved alone in its slot, and is named,
when every other resting wearable stayed still (no move within ``SAME_MOVE_S``, and their readings still while its
moved: a knock just after a turn, which their detectors took as the turn's end); else the tray moved. So is a move
before a turn was checked: a wearable that moved alone is named loose and its turn closed by the kit; when the tray
moved, the fault is judged as a turn's. Neither is judged alone while another wearable still ends that turn: its
detector finds a knock in the turn's pause only when it closes the turn's stage, seconds later.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Protocol

from .codes import STEPS, EndReason, Phase, State
from .turn_checks import HeldFault, HeldMove
from .turns import TurnRecord

HOLD_S = 0.5  # device time a wearable's fault waits for the others' readings of the same moment (a knock reaches
# each wearable's detector up to a few tenths of a second apart) before another's passing that turn makes it its own
WAIT_S = 2.0  # ... and at most this long for the verdicts of those still checking that turn
SAME_MOVE_S = 1.0  # two wearables' moves this close (each on its own clock, counted back from now) are one move
MOVE_SEEN_S = 3.0  # a detector sees a move for what it is up to this long after it (a knock in a turn's pause: once
# the rest after it is long enough to close the turn's stage)
ARRIVAL_S = 0.25  # the wearables' samples of one moment arrive this far apart at most (their links batch them)
CHECKING_WAIT_S = 10.0  # at most this long for wearables still checking the turn before a move is judged one's own
RESTING = frozenset({Phase.WAITING, Phase.SETTLE, Phase.READY, Phase.CHECKING, Phase.PAUSE})  # held still, or to be
AT_THE_TURN = frozenset({Phase.TURNING, Phase.PLACING, Phase.CHECKING, Phase.PAUSE})
ENDING_THE_TURN = frozenset({Phase.TURNING, Phase.PLACING, Phase.CHECKING})
NOT_FOLLOWING = frozenset({State.CONNECTING, State.RECONNECTING})


class Readings(Protocol):
    """What the judgement reads of a wearable's own readings (server.live.stream.SessionStream)."""

    def move_span(self, at_t: float, within_s: float) -> tuple[float, float] | None: ...

    def moved_between(self, t0: float, t1: float) -> bool: ...

    def still_between(self, t0: float, t1: float) -> bool: ...

    def wall_offset(self) -> float | None: ...


class Wearable(Protocol):
    """What the judgement uses of a kit wearable's guided session (server.live.session.GuidedSession)."""

    device_id: str
    state: State
    phase: Phase | None
    held_fault: HeldFault | None
    held_move: HeldMove | None
    moves: list[float]
    kit_closed: set[str]
    t_now: float

    @property
    def stream(self) -> Readings: ...

    @property
    def turns(self) -> Mapping[str, TurnRecord]: ...

    @property
    def axis(self) -> str | None: ...

    @property
    def finished(self) -> bool: ...

    def release_held(self) -> None: ...

    def kit_closes_turn(self, passed: list[str], moved_alone: bool) -> None: ...

    def say_move(self, alone_of: list[str] | None) -> None: ...

    def kit_not_turned(self, turned: list[str]) -> None: ...


def _step(w: Wearable) -> int:
    return STEPS.index(w.state) if w.state in STEPS else 0


def _shift(w: Wearable, o: Wearable) -> float:
    """From ``w``'s device clock to ``o``'s (s): the wearables' clocks differ, but their samples of one moment leave
    together, so that moment is where each one's readings that reached the service soonest put it (a while the service
    reads one of them late does not move it); without those, where each one's readings have come to now."""
    off_w, off_o = w.stream.wall_offset(), o.stream.wall_offset()
    return off_w - off_o if off_w is not None and off_o is not None else o.t_now - w.t_now


def _span(w: Wearable, at_t: float) -> tuple[float, float]:
    """The move ``w`` saw at its device time ``at_t``, as its readings have it (only that moment when they do not)."""
    return w.stream.move_span(at_t, MOVE_SEEN_S) or (at_t, at_t)


def _moved_with(w: Wearable, at_t: float, others: Sequence[Wearable]) -> list[Wearable]:
    """The ``others`` that moved at the moment ``w`` did (its device time ``at_t``): a move they saw then, or their
    readings moving while ``w``'s did (a knock just after a turn, which their detectors took as the turn's end)."""
    start, end = _span(w, at_t)

    def moved(o: Wearable) -> bool:
        shift = _shift(w, o)
        if any(abs(t - (at_t + shift)) <= SAME_MOVE_S for t in o.moves):
            return True
        return o.stream.moved_between(start + shift - ARRIVAL_S, end + shift + ARRIVAL_S)

    return [o for o in others if moved(o)]


def _behind(w: Wearable, at_t: float, others: Sequence[Wearable]) -> list[Wearable]:
    """The ``others`` whose readings have not yet come past the moment ``w`` moved (its device time ``at_t``): the
    service reads them later than ``w``'s, so their stillness says nothing of that move yet."""
    end = _span(w, at_t)[1]
    return [o for o in others if o.t_now < end + _shift(w, o) + ARRIVAL_S]


def _still_checking(w: Wearable, others: Sequence[Wearable]) -> list[Wearable]:
    """The ``others`` that have not yet judged ``w``'s turn: a move in its pause reaches the detector of one still
    ending that turn only when the turn's stage closes (seconds later, the move then merged into it), so until then
    its stillness says nothing of the move."""
    return [o for o in others if o.state == w.state and o.phase in ENDING_THE_TURN and o.held_fault is None
            and w.axis not in o.turns]


def judge_held(wearables: Sequence[Wearable]) -> bool:
    """Judge every held fault and move that can be judged now; True while some stay held (judge again shortly)."""
    following = [w for w in wearables if not w.finished and w.state not in NOT_FOLLOWING]
    for w in following:
        move = w.held_move
        if move is None or w.t_now - move.seen_t < HOLD_S:  # the others see the same move about as late
            continue
        others = [o for o in following if o is not w]
        if _still_checking(w, others) and w.t_now - move.seen_t < CHECKING_WAIT_S:
            continue
        resting = [o for o in others if o.phase in RESTING]
        behind = _behind(w, move.at_t, resting)
        if behind and w.t_now - move.seen_t < CHECKING_WAIT_S:
            continue
        alone = bool(resting) and not behind and not _moved_with(w, move.at_t, resting)
        w.say_move([o.device_id for o in resting] if alone else None)
    for w in following:
        held = w.held_fault
        if held is None:
            continue
        waited = w.t_now - held.at_t
        others = [o for o in following if o is not w]
        resting = [o for o in others if o.phase in RESTING]
        behind = _behind(w, held.at_t, resting) if held.code == EndReason.MOVED_DURING_PAUSE else []
        if behind and waited < CHECKING_WAIT_S:
            continue
        if held.code == EndReason.MOVED_DURING_PAUSE and waited >= HOLD_S and resting and not behind \
                and not _moved_with(w, held.at_t, resting) \
                and not any(o.held_fault is not None for o in others if o.state == w.state) \
                and (not _still_checking(w, others) or waited >= CHECKING_WAIT_S):
            w.kit_closes_turn([o.device_id for o in resting], moved_alone=True)  # the tray stayed still
            continue
        at_turn = [o for o in following if o.state == w.state and o.phase in AT_THE_TURN]
        # past this turn, or in the pause after it with the turn recorded (one whose fault the kit closed rests there
        # without it), in the kit's order
        # (one whose own fault of this turn the kit closed is past it, but did not pass it)
        passed = [o for o in following if (_step(o) > _step(w) and w.axis not in o.kit_closed)
                  or (o in at_turn and o.held_fault is None and o.phase == Phase.PAUSE and w.axis in o.turns)]
        undecided = [o for o in at_turn if o.held_fault is None and o.phase != Phase.PAUSE]
        if not passed and not undecided:  # every wearable at this turn saw a fault: the tray's
            for o in at_turn:
                o.release_held()
        elif passed and waited >= (WAIT_S if undecided else HOLD_S):
            w.kit_closes_turn([o.device_id for o in passed], moved_alone=False)
    return any(w.held_fault is not None or w.held_move is not None for w in following)


def judge_not_turned(wearables: Sequence[Wearable]) -> None:
    """A wearable still waiting for a turn that every other wearable of the kit has made, whose readings all through
    that turn (read past its end, on its own clock) stayed still, did not turn with the tray: it is not in the tray, or
    not switched on. The kit says so once and closes that turn for it, so that it follows the tray's steps."""
    following = [w for w in wearables if not w.finished and w.state not in NOT_FOLLOWING]
    for w in following:
        axis = w.axis
        if w.phase != Phase.READY or axis is None or axis in w.turns or axis in w.kit_closed:
            continue
        others = [o for o in following if o is not w]
        past = [o for o in others if _step(o) > _step(w) or (o.state == w.state and o.phase == Phase.PAUSE)]
        made = [o for o in past if axis in o.turns and axis not in o.kit_closed]  # (past it, some closed by the kit)
        if not others or len(past) < len(others) or not made:
            continue
        spans = [(o.turns[axis].start_s + _shift(o, w), o.turns[axis].end_s + _shift(o, w)) for o in made]
        if w.t_now < max(end for _, end in spans) + ARRIVAL_S:  # its readings of the turn's end have not come yet
            continue
        if all(w.stream.still_between(start - ARRIVAL_S, end + ARRIVAL_S) for start, end in spans):
            w.kit_not_turned([o.device_id for o in made])
