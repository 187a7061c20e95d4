"""What the guided session says to the clinician: prompts, warnings and failure reasons.

Every failure names what happened and how to fix it, in words a clinician understands. "The device" is only ever
what the clinician's hand holds, puts down and turns; "the wearable" is the unit itself: its link, its data, its sensor,
its calibration. A kit says every "the device" of the tray its wearables ride in (server.live.kit_guidance).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Sequence

from calib.judge.acceptance import Check
from calib.units import FULL_TURN_DEG

from .codes import EndReason

AXIS_NAMES = {"x": "X", "y": "Y", "z": "Z"}

# reason codes of a failed session, with a one-line description for the docs and the API schema
REASONS: dict[EndReason, str] = {
    EndReason.CONNECT_FAILED: "the wearable could not be connected or did not start streaming",
    EndReason.NOT_STILL: "the device never stayed still long enough before the first turn",
    EndReason.NO_MOTION: "the requested turn did not start within the time limit",
    EndReason.MOVED_DURING_PAUSE: "the device moved during a pause between turns",
    EndReason.WRONG_AXIS: "the turn was about another axis than the one asked for",
    EndReason.TOO_FAST: "the turn was so fast that the gyroscope saturated",
    EndReason.TURN_INCOMPLETE: "the turn was less than a full turn",
    EndReason.TURN_TOO_FAR: "the turn was more than a full turn",
    EndReason.TURN_TOO_LONG: "the turn did not end within the time limit",
    EndReason.SAMPLE_LOSS: "samples were lost on the radio link during a turn",
    EndReason.LINK_LOST: "the radio link was lost and did not come back in time",
    EndReason.UNREADABLE_DATA: "the wearable sent data this version of gyrocal cannot read, or packets malformed, so many "
                               "or within a turn that it cannot be calibrated (not the hand, not the radio)",
    EndReason.DEVICE_CLOCK: "the wearable's time stamps ran far ahead of real time: its clock, or its data, cannot be "
                            "trusted (not the hand, not the radio)",
    EndReason.SENSOR_FAULT: "the sensor read values a working sensor cannot give (a stuck or saturated axis, gravity off)",
    EndReason.OUT_OF_TOLERANCE: "the computed calibration is outside the documented tolerances",
    EndReason.CALIBRATION_FAILED: "the estimator could not compute a calibration from the recording",
    EndReason.DEPARTED: "the wearable came apart from the rest of its kit (it moved in its slot): no calibration from that kit",
    EndReason.TIMEOUT: "the session did not reach its end within the overall time limit",
    EndReason.SERVICE_OVERLOADED: "the service itself fell too far behind to follow the session (not the wearable, not the hand)",
    EndReason.SERVICE_RESTARTED: "the service was restarted while the session ran",
    EndReason.GATEWAY_LOST: "the gateway running the session stopped answering",
    EndReason.INTERNAL_ERROR: "an unexpected error stopped the session",
    EndReason.CANCELLED: "an operator cancelled the session",
}


def ax(axis: str) -> str:
    return AXIS_NAMES.get(axis, axis.upper())


def again(retry: bool, axis: str | None = None) -> str:
    if retry and axis:
        return f"Put the device back against the block, wait for the prompt and turn again about {ax(axis)}."
    return "Start a new calibration."


MOVED_RESTART = "The device moved: the count starts again. Keep it still against the block."

PROMPTS = {
    "connecting": "Connecting to the wearable…",
    "still": "Put the device on the table against the block and take your hands off it.",
    "settle": "Put the device back against the block and keep it still.",
    "computing": "Computing the calibration…",
    "reconnecting": "The connection to the wearable was lost. Keep the device still and close to the receiver; "
    "the session resumes when it reconnects.",
}


def turn_prompt(axis: str) -> str:
    return f"Turn the device one full turn (360°) about its {ax(axis)} axis, then put it back against the block."


def returning_prompt(axis: str) -> str:
    return f"Putting it back against the block: then turn it one full turn about its {ax(axis)} axis."


def turning_prompt(axis: str) -> str:
    return f"Turning about {ax(axis)}: stop when the device is back in its place against the block."


def placing_prompt(axis: str, calibrated: bool) -> str:
    if calibrated:
        return f"Put the device back against the block and hold it still: the turn about {ax(axis)} is checked once it rests."
    return (f"Hold it still. If the device is back in its place against the block, leave it there; "
            f"if not, finish the turn about {ax(axis)} first.")


def checking_prompt(axis: str) -> str:
    return f"Checking the turn about {ax(axis)}: keep the device still against the block."


def pause_prompt(axis: str, next_axis: str | None) -> str:
    then = f" before the turn about {ax(next_axis)}" if next_axis else ""
    return f"Turn about {ax(axis)} recorded. Keep the device still against the block{then}."


def done_prompt(passed: bool) -> str:
    if passed:
        return "Calibration computed and within tolerances. Accept it to make it the wearable's calibration, or discard it."
    return "The calibration is outside the tolerances."


# -- failure and warning texts: (what happened) + (how to fix it) -----------------------------------------------
def not_still(target_s: float, limit_s: float) -> str:
    return (
        f"The device did not stay still for {target_s:g} s within {limit_s:g} s. "
        "Put it on the table against the block, take your hands off it, and start a new calibration."
    )


def not_still_hint(target_s: float) -> str:
    return f"Still waiting for {target_s:g} s of rest: put the device down against the block and don't touch it."


def no_motion(axis: str, limit_s: float) -> str:
    return f"No turn about {ax(axis)} started within {limit_s:g} s. Start a new calibration and turn the device when asked."


def no_motion_hint(axis: str) -> str:
    return f"Waiting for the turn: pick the device up and turn it one full turn about its {ax(axis)} axis now."


def moved_during_pause(axis: str, pause_s: float, retry: bool, turn_recorded: bool) -> str:
    """The device moved in the rest after a turn. ``turn_recorded``: the turn had passed its checks
    (a retry repeats only the pause); if not (it moved before the rest could close the turn), a retry
    asks for the turn again."""
    if not retry:
        fix = (f"Start a new calibration and, after each turn, keep the device still against the block for {pause_s:g} s, "
               "until the countdown ends.")
    elif turn_recorded:
        fix = "Keep the device still against the block until the countdown ends; the pause starts again."
    else:
        fix = f"{again(True, axis)} After the turn, keep the device still against the block until the countdown ends."
    what = "" if turn_recorded else ", before that turn could be checked"
    return f"The device moved during the pause after the turn about {ax(axis)}{what}. {fix}"


def wrong_axis(expected: str, got: str, retry: bool) -> str:
    return (f"That turn was about {ax(got)}, not {ax(expected)}. {again(retry, expected)} "
            f"Turn about the {ax(expected)} axis marked on the case.")


def too_fast(axis: str, full_scale: float | None, retry: bool, duration_s: float | None = None) -> str:
    fs = f" (±{full_scale:g} °/s)" if full_scale else ""
    took = f"took {duration_s:.1f} s: " if duration_s else "was "
    return (f"That turn about {ax(axis)} {took}too fast, the sensor reached its limit{fs}. {again(retry, axis)} "
            "Turn more slowly, taking 2–4 s for the whole turn.")


def turn_incomplete(axis: str, angle: float, retry: bool) -> str:
    return (
        f"The turn about {ax(axis)} measured {abs(angle):.0f}°, not a full turn. {again(retry, axis)} "
        "Turn a full 360° until the device is back in its starting position against the block."
    )


def turn_too_far(axis: str, angle: float, retry: bool) -> str:
    return (
        f"The turn about {ax(axis)} measured {abs(angle):.0f}°, more than one full turn. {again(retry, axis)} "
        "Turn exactly once, stopping when the device is back against the block."
    )


def not_one_axis(axis: str, off_deg: float, retry: bool) -> str:
    return (
        f"The turn about {ax(axis)} also turned the device {off_deg:.0f}° about the other axes. {again(retry, axis)} "
        f"Turn about the {ax(axis)} axis only, keeping the device level."
    )


def ended_off(axis: str, tilt_deg: float, retry: bool) -> str:
    """A turn that ended tilted from where it began (more than a hand's usual placement): put down off its place, or
    not a full turn about a slightly tilted axis."""
    said = (f"Turn {ax(axis)} ended {tilt_deg:.1f}° off where it began: the device was not put back flat where it "
            "started, or the turn was not a full one.")
    if retry:  # what to do in one sentence: on a phone the notice and the turn's gauge share the first screen
        return (f"{said} Put it back flat against the block, exactly where it started, wait for the prompt and turn "
                f"again about {ax(axis)}.")
    return f"{said} {again(retry, axis)} Put it down flat, against the block, exactly where it started."


def not_back(axis: str, tilt_deg: float, retry: bool) -> str:
    return (
        f"After the turn about {ax(axis)} the device rests {tilt_deg:.0f}° away from its starting position, so the turn "
        f"was not a full one. {again(retry, axis)} Turn until the device is back in the same place against the block."
    )


def turn_too_long(axis: str, limit_s: float, retry: bool) -> str:
    return (f"The turn about {ax(axis)} did not end within {limit_s:g} s. {again(retry, axis)} "
            "Put the device down against the block after one turn.")


def readings(n: int) -> str:
    return f"{n} reading was" if n == 1 else f"{n} readings were"


def sample_loss(axis: str, lost: int, retry: bool) -> str:
    return (
        f"{readings(lost)} lost on the radio link during the turn about {ax(axis)}. {again(retry, axis)} "
        "Keep the device within a few metres of the receiver, with nothing in between."
    )


def link_lost(limit_s: float) -> str:
    return (
        f"The connection to the wearable was lost and did not come back within {limit_s:g} s. "
        "Check that the wearable is switched on, charged and close to the receiver, then start a new calibration."
    )


def stream_stopped() -> str:
    return "The wearable stopped sending data. Check that it is switched on and charged, then start a new calibration."


def link_restored(axis: str | None) -> str:
    if axis:
        return f"Reconnected. The turn about {ax(axis)} will be done again: put the device back against the block and keep it still."
    return "Reconnected. Put the device back against the block and keep it still."


def no_data(silent_s: float) -> str:
    return (f"No data from the wearable for {silent_s:.0f} s. Keep it still and close to the receiver: "
            "the session carries on as soon as its data arrives.")


def data_resumed(late_s: float) -> str:
    return f"The wearable's data arrived {late_s:.1f} s late, complete: nothing was lost. Carry on."


def sensor_fault(detail: str) -> str:
    """The session's end for a faulty sensor (server.live.sensor_faults): what was seen and what to do."""
    return (f"{detail} This is not the way the device was held or turned. Switch the wearable off and on and start a "
            "new calibration; if it happens again, the wearable needs repair or replacement.")


def service_late(late_s: float) -> str:
    return (f"The calibration service fell {late_s:.1f} s behind (the computer running it is busy). It is catching up "
            "with the data it received: nothing was lost, and nothing needs to be done again.")


def service_overloaded(late_s: float) -> str:
    return (f"The calibration service fell {late_s:.0f} s behind the wearable and could not follow the calibration: the "
            "computer running it is overloaded. This was not the wearable, nor the way the device was turned. Start a new "
            "calibration; if it happens again, tell the administrator.")


def _turn_reading(c: Check) -> tuple[str, str] | None:
    """A scale factor out of range as the turn that gave it: what it read, and how to turn it again (None: the check
    is not a scale factor)."""
    if c.name != "k" or not isinstance(c.limit, tuple) or c.value is None or not math.isfinite(c.value) or c.value <= 0:
        return None  # not a scale factor, or one not determined (its axis was not turned): its check says so
    low, high = FULL_TURN_DEG / c.limit[1], FULL_TURN_DEG / c.limit[0]
    reads = FULL_TURN_DEG / c.value
    said = f"the turn about {ax(c.axis or '')} read {reads:.0f}°, where a working sensor reads a full turn as {low:.0f}° to {high:.0f}°"
    todo = (f"turn {ax(c.axis or '')} all the way round, until the device is back against the block" if reads < low
            else f"turn {ax(c.axis or '')} exactly once, stopping when the device is back against the block")
    return said, todo


def _worst_closure(failed: Sequence[Check]) -> Check | None:
    """The turn that came back furthest from where it was put (a closure check that failed), if any."""
    closures = [c for c in failed if c.name == "closure" and c.axis in AXIS_NAMES and c.value is not None
                and math.isfinite(c.value)]
    return max(closures, key=lambda c: float(c.value or 0.0)) if closures else None


def _closure_reading(c: Check) -> tuple[str, str]:
    said = (f"the turn about {ax(c.axis or '')} ends {c.value:.1f}° from where the device was put back, where a full "
            f"turn comes back within {c.limit:g}°")
    return said, f"turn {ax(c.axis or '')} all the way round, until the device is back against the block"


def scale_factor_turns(failed: Sequence[Check]) -> list[str]:
    """The turns whose scale factor is out of range, in protocol order."""
    return sorted({c.axis for c in failed if c.axis is not None and _turn_reading(c) is not None})


def turns_to_redo(failed: Sequence[Check]) -> list[str]:
    """The turns to ask again: those whose scale factor is out of range (most likely a hand's turn that was not a full
    one; the other checks it spoils, such as the other turns' closure, are judged again with the new turn), in
    protocol order; without one, the turn that came back furthest from where it was put (a turn about the vertical
    that stopped short leaves its k in range and every turn unable to close, that one most)."""
    short = scale_factor_turns(failed)
    if short:
        return short
    worst = _worst_closure(failed)
    return [worst.axis] if worst is not None and worst.axis is not None else []


def redo_turns(failed: Sequence[Check]) -> str:
    """Why the result asks for a turn again (its scale factors out of range, or the turn furthest from closing), and
    how to make it."""
    readings = [r for r in map(_turn_reading, failed) if r is not None]
    worst = _worst_closure(failed)
    if not readings and worst is not None:
        readings = [_closure_reading(worst)]
    said = "; ".join(r[0] for r in readings)
    todo = "; then ".join(r[1] for r in readings)
    one = len(readings) == 1
    return (f"{said[:1].upper()}{said[1:]}: most likely {'it was' if one else 'they were'} not a full turn. "
            f"Once more: {todo}.")


def _failure(name: str, axis: str | None) -> tuple[str, str | None]:
    """A failed check as a way of failing: a scale factor or bias per axis; turns that do not close, whichever turn
    shows it (one turn that is not a full one spoils the others' closure, and which shows most varies)."""
    return (name, None) if name == "closure" else (name, axis)


def out_of_tolerance(failed: Sequence[Check], failed_before: Collection[tuple[str, str | None]] = (),
                     hand_turns: bool = True) -> str:
    """Why a result failed, and what to redo. From full turns made by hand (``hand_turns``: a guided session, or a
    recording of the paper's protocol) a scale factor out of range most likely comes from the hand: its turn was not a
    full one (a working sensor reads a full turn as 360°/k, within the range's readings), so that turn is named with
    what to do; "the sensor may be faulty" is said only when the device failed the same check the time before
    (``failed_before``: (name, axis) of its last failed result)."""
    undetermined = [c for c in failed if c.name == "k" and (c.value is None or not math.isfinite(c.value))]
    if undetermined and len(undetermined) == len(failed):
        axes = " and ".join(ax(c.axis or "") for c in undetermined)
        return (f"The calibration is incomplete: there was no usable full turn about {axes}, so "
                f"{'its scale factor is' if len(undetermined) == 1 else 'their scale factors are'} not determined. "
                f"Record the protocol again with a full 360° turn about each axis, {axes} included.")
    said, todo = [], []
    for c in failed:
        turn = _turn_reading(c) if hand_turns else None
        if turn is not None:
            said.append(turn[0])
            todo.append(turn[1])
        else:
            said.append(c.text)
    why = "The calibration is outside the tolerances: " + "; ".join(said) + ". "
    if todo:
        why += "Most likely that turn was not a full one: start a new calibration and " + "; ".join(todo) + "."
    elif hand_turns:
        why += ("Check that the device rested against the block and that each turn was one full turn about the asked "
                "axis, then start a new calibration.")
    else:
        why += ("Check the recording's units (raw counts need their sensitivities) and that the device rested in each "
                "pose, then record it again.")
    if {_failure(c.name, c.axis) for c in failed} & {_failure(n, a) for n, a in failed_before}:
        why += " It failed the same way the time before: the sensor may be faulty; have the wearable checked."
    return why


def connect_failed(detail: str) -> str:
    return (f"Could not connect to the wearable ({detail}). Check that it is switched on, charged and in range, then start "
            "a new calibration.")


def compute_timeout(limit_s: float, what: str = "the calibration") -> str:
    """The estimator ran out of time: on a working service it takes a second or two, so the service is overloaded."""
    return (f"Computing {what} took longer than {limit_s:g} s and was stopped: the service is overloaded, not the wearable "
            "nor the way the device was turned. Start a new calibration; if it happens again, tell the administrator.")


def timeout(limit_s: float) -> str:
    return f"The calibration did not finish within {limit_s / 60:g} minutes and was stopped. Start a new calibration."


def internal_error(detail: str) -> str:
    return f"An internal error stopped the calibration ({detail}). Start a new calibration; if it happens again, report it."


def decided(decision: str) -> str:
    """The prompt once the operator accepted or discarded the result."""
    if decision == "accepted":
        return "Calibration accepted: it is now the wearable's current calibration."
    return "Result discarded: the wearable keeps its previous calibration."
