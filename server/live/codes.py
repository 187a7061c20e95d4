"""The words a guided session is told in, one enum each, published in the API schema: its states, the
phases of a turn, and why it ended (the page maps every EndReason to a title and a fix, and a test holds
the two in step)."""

from __future__ import annotations

from enum import StrEnum


class State(StrEnum):
    """Where a session is, in protocol order, then the end states."""

    CONNECTING = "connecting"
    STILL = "still"
    TURN_X = "turn_x"
    TURN_Y = "turn_y"
    TURN_Z = "turn_z"
    RECONNECTING = "reconnecting"
    COMPUTING = "computing"
    DONE = "done"
    FAILED = "failed"
    CANCELLED = "cancelled"


class Phase(StrEnum):
    """Within the still and turn states: waiting for rest, settling after a reconnection or retry, asking for
    the turn, returning (after a turn asked again, a motion that may only be the device put back in its place),
    turning, placing (the turn's motion has stopped: waiting for the device to rest in its place),
    checking (it rests after what looks like a full turn: the turn counts once its closing rest is complete),
    and the pause after a recorded turn."""

    WAITING = "waiting"
    SETTLE = "settle"
    READY = "ready"
    RETURNING = "returning"
    TURNING = "turning"
    PLACING = "placing"
    CHECKING = "checking"
    PAUSE = "pause"


class EndReason(StrEnum):
    """Why a session ended other than done (its ``reason_code``)."""

    CONNECT_FAILED = "connect_failed"
    NOT_STILL = "not_still"
    NO_MOTION = "no_motion"
    MOVED_DURING_PAUSE = "moved_during_pause"
    WRONG_AXIS = "wrong_axis"
    TOO_FAST = "too_fast"
    TURN_INCOMPLETE = "turn_incomplete"
    TURN_TOO_FAR = "turn_too_far"
    TURN_TOO_LONG = "turn_too_long"
    SAMPLE_LOSS = "sample_loss"
    LINK_LOST = "link_lost"
    UNREADABLE_DATA = "unreadable_data"
    DEVICE_CLOCK = "device_clock"
    SENSOR_FAULT = "sensor_fault"
    OUT_OF_TOLERANCE = "out_of_tolerance"
    CALIBRATION_FAILED = "calibration_failed"
    DEPARTED = "departed"
    TIMEOUT = "timeout"
    SERVICE_OVERLOADED = "service_overloaded"
    SERVICE_RESTARTED = "service_restarted"
    GATEWAY_LOST = "gateway_lost"
    INTERNAL_ERROR = "internal_error"
    CANCELLED = "cancelled"


def known_reason(code: str | None) -> EndReason | None:
    """A stored reason code this version knows; one a newer gyrocal on the same store wrote is left out (the reason in
    words is still shown) rather than making the session unreadable while a fleet's gateways are upgraded one by one."""
    return EndReason(code) if code is not None and code in {r.value for r in EndReason} else None


TURN_STATES = {"x": State.TURN_X, "y": State.TURN_Y, "z": State.TURN_Z}
STEPS = (State.CONNECTING, State.STILL, State.TURN_X, State.TURN_Y, State.TURN_Z, State.COMPUTING, State.DONE)
END_STATES = frozenset({State.DONE, State.FAILED, State.CANCELLED})
