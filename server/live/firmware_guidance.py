"""What the service says of a wearable whose stream shows its firmware at fault, not the radio or the hand: packets it
cannot read, malformed packets in a turn or in numbers, time stamps that run ahead of real time.

The session and its runner judge (server.live.stream_faults, server.live.stream); this module only words it.
"""

from __future__ import annotations

from .guidance import again, ax

# what each reason a decoder drops a packet for means, said to a clinician (server.link: malformed_reasons)
UNREADABLE_WHY = {
    "version": "a packet format this version of gyrocal does not know",
    "n_mismatch": "packets with another number of samples than the configuration it reported",
    "config_id": "packets of another configuration than the one it reported",
    "length": "packets of the wrong length",
    "short": "packets too short to hold a sample",
    "flags": "packets with flags this version does not know",
    "inconsistent": "packets whose sequence numbers and time stamps disagree",
}


def refused_list(refused: dict[str, int]) -> str:
    """The packets refused, by reason, the most frequent first: "packets of the wrong length (208); ..."."""
    return "; ".join(f"{UNREADABLE_WHY.get(reason, reason)} ({count})" for reason, count in
                     sorted(refused.items(), key=lambda kv: -kv[1]))


def unreadable_data(refused: dict[str, int], firmware: str | None) -> str:
    """The wearable is on and sending, but nothing it sends can be read."""
    n, what = sum(refused.values()), refused_list(refused)
    fw = f" (firmware {firmware})" if firmware else ""
    return (f"The wearable{fw} is sending data this version of gyrocal cannot read: {n} packets refused, {what}. "
            "It is not the radio link and not the way the device was turned. Start a new calibration; if it happens "
            "again, the wearable's firmware and this service do not match: update gyrocal or the wearable.")


def refused_in_turn(axis: str, refused: int, retry: bool) -> str:
    what = f"{refused} reading{'' if refused == 1 else 's'} of the turn about {ax(axis)}"
    return (f"{what} came in malformed packets from the wearable's firmware, which gyrocal refused: the turn has a "
            f"gap. {again(retry, axis)} It is not the radio link and not the way "
            "the device was turned; if it happens again, the wearable's firmware and this service do not match: update "
            "gyrocal or the wearable.")


def malformed_stream(refused: dict[str, int], readable: int, firmware: str | None) -> str:
    """The wearable sends, but too many of its packets are malformed for a calibration."""
    n, what = sum(refused.values()), refused_list(refused)
    fw = f" (firmware {firmware})" if firmware else ""
    return (f"The wearable{fw} sends many packets gyrocal cannot read: {n} of {n + readable} refused, {what}. A "
            "calibration needs every reading of a turn. It is not the radio link and not the way the device was "
            "turned. Switch the wearable off and on and start a new calibration; if it happens again, its firmware "
            "and this service do not match: update gyrocal or the wearable.")


def device_clock_ahead(ahead_s: float, over_s: float, firmware: str | None) -> str:
    """The wearable's time stamps ran ahead of the service's clock by more than a clock can drift."""
    fw = f" (firmware {firmware})" if firmware else ""
    return (f"The wearable's time stamps{fw} ran {ahead_s:.0f} s ahead of this computer's clock in {over_s:.1f} s: no "
            "sensor measures faster than real time, so its clock, or the data it sends, cannot be trusted. It is not "
            "the radio link and not the way the device was turned. Switch the wearable off and on and start a new "
            "calibration; if it happens again, the wearable's firmware is at fault: update it or have it repaired.")
