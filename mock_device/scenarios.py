"""The scripted clinician: what the hand does once streaming starts, and the faults it can make.

Every scenario starts from the paper's protocol (rest ~3 s, a full turn about x, rest, y, rest, z,
rest), with the turn durations, tilts, wobbles and speed profiles drawn from the seed, and changes
one thing:

- ``normal``: the protocol as the paper describes it.
- ``moved_during_still``: the hand bumps the device (about 12 deg and back) in the pause after the x turn.
- ``wrong_axis``: the second turn is about z instead of y (so z is turned twice and y never).
- ``too_fast``: every turn takes 0.6 s; peak rates pass the gyro's +-500 deg/s range and clip.
- ``stops_short``: the z turn stops at 320 deg instead of 360 deg.
- ``link_drop``: the radio link drops halfway through the y turn; the device is out of range 1.5 s.
- ``packet_loss``: 2 % of the data packets never arrive (seeded, independent per packet).
- ``dropped``: the protocol, but the device was dropped after its second session: from the third on, its x scale
  factor is 4 % higher (what the departure check of a new calibration must catch).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from calib.errors import GyrocalError
from calib.simulator import Motion, ProtocolScript, Still, Turn, paper_protocol_script


@dataclass(frozen=True)
class LinkFaults:
    """Faults of the radio link, in device time (seconds since streaming started)."""

    drop_at_s: float | None = None  # the link drops at this session time (once)
    drop_for_s: float = 1.5  # then the device is out of range (not advertising) this long
    packet_loss: float = 0.0  # probability that a data packet is never delivered
    fail_connects: int = 0  # this many connection attempts drop before services are resolved


@dataclass(frozen=True)
class Scenario:
    """A named clinician script and link faults."""

    name: str
    description: str
    build: Callable[[np.random.Generator], ProtocolScript]
    faults: LinkFaults = field(default_factory=LinkFaults)
    # set by faults that depend on the script (e.g. "halfway through the y turn")
    fault_builder: Callable[[ProtocolScript], LinkFaults] | None = None
    # the sensor's scale factors change by this factor from session ``damaged_from`` on (a drop); None: never
    damaged_from: int | None = None
    damage_k: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def script(self, rng: np.random.Generator) -> ProtocolScript:
        return self.build(rng)

    def link_faults(self, script: ProtocolScript) -> LinkFaults:
        return self.fault_builder(script) if self.fault_builder else self.faults


def _normal(rng: np.random.Generator) -> ProtocolScript:
    return paper_protocol_script(rng)


def _moved_during_still(rng: np.random.Generator) -> ProtocolScript:
    segs = list(paper_protocol_script(rng).segments)
    pause = segs[2]  # the rest after the x turn
    half = pause.duration_s / 2
    bump = np.array([4.0, -3.0, 12.0])
    segs[2:3] = [Still(half - 0.4), Motion(bump, 0.4), Motion(-bump, 0.4), Still(half - 0.4)]
    return ProtocolScript(tuple(segs))


def _wrong_axis(rng: np.random.Generator) -> ProtocolScript:
    segs = list(paper_protocol_script(rng).segments)
    y = segs[3]
    segs[3] = Turn("z", y.angle_deg, duration_s=y.duration_s, wobble_deg=y.wobble_deg, tilt=y.tilt, profile=y.profile)
    return ProtocolScript(tuple(segs))


def _too_fast(rng: np.random.Generator) -> ProtocolScript:
    segs = [replace_turn(s, duration_s=0.6) if isinstance(s, Turn) else s for s in paper_protocol_script(rng).segments]
    return ProtocolScript(tuple(segs))


def _stops_short(rng: np.random.Generator) -> ProtocolScript:
    segs = list(paper_protocol_script(rng, angle_deg=(360.0, 360.0, 320.0)).segments)
    z = segs[5]
    # spun flat on the table, about the vertical itself: short, it ends turned on the table, not tilted, so only its
    # reading can tell (a short turn about a tilted axis ends tilted, and the session asks it again at once)
    segs[5] = replace_turn(z, tilt=(0.0, 0.0), wobble_deg=0.0)
    return ProtocolScript(tuple(segs))


def replace_turn(turn: Turn, **changes: object) -> Turn:
    """A copy of a Turn with some fields changed (Turn validates in __post_init__)."""
    return replace(turn, **changes)


def _mid_y_turn(script: ProtocolScript) -> LinkFaults:
    t = 0.0
    turns = 0
    for seg in script.segments:
        if isinstance(seg, Turn):
            turns += 1
            if turns == 2:
                return LinkFaults(drop_at_s=t + seg.duration_s / 2, drop_for_s=1.5)
        t += seg.duration_s
    raise AssertionError("the protocol script has no second turn")


SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario("normal", "the protocol as the paper describes it", _normal),
        Scenario("moved_during_still", "a bump of the device during the pause after the x turn", _moved_during_still),
        Scenario("wrong_axis", "the second turn is about z instead of y", _wrong_axis),
        Scenario("too_fast", "0.6 s turns: the gyro saturates at +-500 deg/s", _too_fast),
        Scenario("stops_short", "the z turn stops at 320 deg", _stops_short),
        Scenario("link_drop", "the link drops halfway through the y turn for 1.5 s", _normal, fault_builder=_mid_y_turn),
        Scenario("packet_loss", "2 % of data packets are lost", _normal, LinkFaults(packet_loss=0.02)),
        Scenario("dropped", "dropped after its second session: x scale factor 4 % higher from then on", _normal,
                 damaged_from=3, damage_k=(1.04, 1.0, 1.0)),
    )
}


def get_scenario(name: str) -> Scenario:
    """The scenario of that name; raises GyrocalError listing the names otherwise."""
    try:
        return SCENARIOS[name]
    except KeyError:
        raise GyrocalError(f"unknown scenario {name!r}: choose one of {', '.join(SCENARIOS)}") from None
