"""The guided protocol's time limits: when waiting turns into a hint, a retry or a failure.

Counted in device time (so they scale with a simulated device's speed) from the start of the current
phase; a pure function of where the session is, the session applies what it returns.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from ..config import ProtocolTimings
from . import guidance as say
from .codes import EndReason, Phase, State


@dataclass(frozen=True)
class Overdue:
    """What a phase that lasted too long leads to: a hint (once), a retry of the turn, or the end of the session."""

    action: Literal["hint", "retry", "fail"]
    code: EndReason | None
    message: str


def time_left(state: str, phase: str | None, axis: str | None, waited_s: float, timings: ProtocolTimings) -> float | None:
    """How long (device s) is left of the ``waited_s`` in this state and phase before ``overdue`` ends the session for
    want of the rest or the turn it asks for; None where no such end comes (a turn under way is asked again instead)."""
    if state == State.STILL or phase == Phase.SETTLE or (axis is not None and phase in (Phase.READY, Phase.PAUSE)):
        return timings.fail_after_s - waited_s
    return None


def overdue(state: str, phase: str | None, axis: str | None, waited_s: float, hinted: bool, timings: ProtocolTimings,
            retry: bool) -> Overdue | None:
    """The consequence of having waited ``waited_s`` in this state and phase, or None while within the limits."""
    tm = timings
    if state == State.STILL or phase == Phase.SETTLE:
        if waited_s > tm.fail_after_s:
            return Overdue("fail", EndReason.NOT_STILL, say.not_still(tm.initial_still_s, tm.fail_after_s))
        if waited_s > tm.hint_after_s and not hinted:
            return Overdue("hint", None, say.not_still_hint(tm.initial_still_s if state == State.STILL else tm.settle_s))
        return None
    if axis is None:
        return None
    if phase == Phase.READY:
        if waited_s > tm.fail_after_s:
            return Overdue("fail", EndReason.NO_MOTION, say.no_motion(axis, tm.fail_after_s))
        if waited_s > tm.hint_after_s and not hinted:
            return Overdue("hint", None, say.no_motion_hint(axis))
    elif phase in (Phase.TURNING, Phase.RETURNING):
        if waited_s > tm.max_turn_s:
            return Overdue("retry", EndReason.TURN_TOO_LONG, say.turn_too_long(axis, tm.max_turn_s, retry))
    elif phase == Phase.PAUSE:
        # a pause that never completes because the device keeps drifting ends like a missed turn
        if waited_s > tm.fail_after_s:
            return Overdue("fail", EndReason.MOVED_DURING_PAUSE, say.moved_during_pause(axis, tm.pause_s, False, True))
    return None
