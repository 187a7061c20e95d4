"""What a kit session says to the clinician holding the tray: a wearable's words said of the tray, and what the kit
does when one wearable lost its link or samples, or saw a fault in a turn the rest of the tray did not."""

from __future__ import annotations

from collections.abc import Sequence

from .guidance import ax


def of_the_tray(text: str) -> str:
    """A wearable's words said of the tray its kit rides in: the clinician holds and turns the tray, not one device.
    In a session's words "the device" is only ever what the hand holds, and "the wearable" the unit itself (its link,
    its data, its sensor, its calibration: server.live.guidance), so every "the device" is the tray here."""
    return text.replace("the device", "the tray").replace("The device", "The tray")


KIT_CONNECTING = "Connecting to the wearables…"


def came_apart(step_deg: float | None) -> str:
    """The reason of a wearable that came apart from its kit. ``step_deg``: how far it turned in its slot while the
    tray rested (calib.kit.departure.Departure.step_deg), when known: of a slip in a turn, the kit knows only that it
    came apart (its own k absorbs the part about the axis being turned)."""
    moved = f" (it turned about {step_deg:.1f}° in its slot while the tray rested)" if step_deg is not None else ""
    return (f"The wearable came apart from the kit{moved}: it moved in its slot, or its readings do not follow the tray. "
            "Seat it firmly in its slot, then calibrate it alone or with the kit.")


NOT_TOGETHER = "The kit could not be calibrated together"  # how every refusal of a whole kit begins


def not_one_motion(wearable: str, reference: str) -> str:
    """Why a kit could not be calibrated together when one wearable's readings do not follow another's (it was not
    in the tray, or its readings stopped), in the clinician's words (calib.errors.KitRefusal)."""
    return (f"{NOT_TOGETHER}: {wearable} did not turn with {reference} (its readings do not "
            f"follow the tray's motion). Check that every wearable of the kit sits in the tray and stays switched on, "
            f"then calibrate the kit again, or {wearable} alone.")


def not_turned(wearable: str, turned: Sequence[str]) -> str:
    """The reason of a kit's wearable whose readings follow none of the others' (calib.kit.together): the kit left it
    out and calibrated the rest."""
    return (f"{wearable} did not turn with the rest of the kit ({', '.join(turned)}): its readings show none of the "
            "tray's motion, so the kit left it out. Check that it sits in the tray and stays switched on, then calibrate "
            "it alone or with the kit.")


def refused(why: str) -> str:
    """Why a kit could not be calibrated together, in calib's words (``why``, one sentence), and what to do."""
    return f"{NOT_TOGETHER}: {why.rstrip('.')}. Start a new calibration."


def kit_link_restored(device_id: str) -> str:
    """A kit's wearable is back: the tray is not turned again for it (the kit bridges what it missed)."""
    return f"Reconnected to {device_id}: the kit goes on."


def kit_sample_loss(device_id: str) -> str:
    """A kit's wearable lost samples in a turn: the tray is not turned again for it (the kit closes that turn)."""
    return (f"{device_id} lost samples on the radio link during a turn. The kit goes on: that turn of {device_id} is "
            "closed with the other wearables'.")


def kit_turn_again(axes: Sequence[str], by: Sequence[str]) -> str:
    """The kit's calibration asks the tray these turns again: ``by`` the wearables whose scale factor for them is out of
    range (empty: every wearable's result points to them, none closing)."""
    named = " and ".join(ax(a) for a in axes)
    one = len(axes) == 1
    if by:
        whose = f"{', '.join(by)}'s scale factor" + ("" if len(by) == 1 else "s")
        found = (f"The kit's calibration found {whose} for {named} out of a working sensor's range: most likely the "
                 f"tray's turn{'' if one else 's'} about {named} {'was' if one else 'were'} not a full turn.")
    else:
        found = (f"The kit's calibration points every wearable to the turn{'' if one else 's'} about {named}: most likely "
                 f"{'that turn was' if one else 'those turns were'} not a full turn.")
    return f"{found} Once more: turn the tray one full turn about {named}, stopping when it is back against the block."


def kit_link_lost(lost: Sequence[str]) -> str:
    return (f"Keep the tray still and close to the receiver: the link to {', '.join(lost)} was lost. "
            "The kit goes on when it reconnects.")


def kit_no_data(silent: Sequence[str]) -> str:
    return (f"Keep the tray still and close to the receiver: no data is coming from {', '.join(silent)}. "
            "The kit goes on as soon as it comes.")


def first_sentence(text: str) -> str:
    """What happened, without what to do about it: a warning's first sentence (its numbers' decimal points kept)."""
    head, dot, _ = text.partition(". ")
    return head + "." if dot else text


def _goes_on(device_id: str) -> str:
    return f"so the tray goes on: that turn of {device_id} is closed with theirs."


def kit_closed_turn(device_id: str, fault: str, passed: Sequence[str]) -> str:
    """A wearable saw a fault in a turn (``fault``: its own words) that the rest of the kit (``passed``) did not: the
    tray is not turned again for it; the kit's calibration closes that turn from the others' readings of it."""
    what = first_sentence(fault).replace("the device", device_id).replace("The device", device_id)
    return f"{device_id}: {what} The rest of the kit ({', '.join(passed)}) passed that turn, {_goes_on(device_id)}"


def kit_clipped_turn(device_id: str, axis: str, full_scale: float | None, passed: Sequence[str]) -> str:
    """A wearable's readings reached its gyroscope's limit in a turn the rest of the kit (``passed``) read whole: its
    sensor's range, not the hand (the others' show the turn was not too fast for them)."""
    fs = f" (±{full_scale:g} °/s)" if full_scale else ""
    return (f"{device_id}'s gyroscope reached its limit{fs} in the turn about {ax(axis)}; the rest of the kit "
            f"({', '.join(passed)}) read that turn whole, {_goes_on(device_id)}")


def kit_moved_alone(device_id: str, axis: str | None, still: Sequence[str]) -> str:
    """A wearable moved while the rest of the kit (``still``) rested: it moved in its slot. ``axis``: in the pause after
    the turn about it (the tray goes on), else while its count of a rest ran (that count starts again)."""
    when = f" during the pause after the turn about {ax(axis)}" if axis else ""
    then = "the tray goes on" if axis else "its count starts again"
    return (f"{device_id} moved{when} while the rest of the kit ({', '.join(still)}) stayed still: it may be loose in "
            f"its slot. Seat it firmly; {then}.")


def kit_not_turned(device_id: str, axis: str, turned: Sequence[str]) -> str:
    """The rest of the kit (``turned``) turned about ``axis``, and this wearable's readings show none of it."""
    return (f"{device_id} did not turn with the rest of the kit ({', '.join(turned)} turned about {ax(axis)}): it may not "
            "be in the tray, or not be switched on. Put it in its slot; the tray goes on without it.")


def kit_tray_moved_unchecked(device_id: str, axis: str, passed: Sequence[str]) -> str:
    """The tray moved before this wearable had checked its turn, after others (``passed``) had checked theirs."""
    return (f"{device_id}: the tray moved before its turn about {ax(axis)} was checked. The rest of the kit "
            f"({', '.join(passed)}) had checked that turn, {_goes_on(device_id)}")
