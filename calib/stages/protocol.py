"""The protocol in a recording's stages: the still before the first turn and the first full turn about each axis,
or a ProtocolError that names what is missing and how to record it."""

from __future__ import annotations

from dataclasses import dataclass, field

from calib.errors import ProtocolError
from calib.stages.config import StageConfig
from calib.stages.stage import AXES, Stage


@dataclass(frozen=True)
class ProtocolStages:
    """The stages the calibration uses: the first still, one turn per axis, and all stills."""

    still0: Stage
    turns: dict[str, Stage]  # keys "x", "y", "z" in that order
    stills: list[Stage]
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        """JSON-ready form."""
        return {
            "still0": self.still0.to_dict(),
            "turns": {a: s.to_dict() for a, s in self.turns.items()},
            "stills": [s.to_dict() for s in self.stills],
            "notes": list(self.notes),
        }


_TURN_HOWTO = "keeping it still for about 3 s before and after"


def find_protocol(stages: list[Stage], min_still0_s: float = 1.5) -> ProtocolStages:
    """The protocol's stages: the still before the first turn and the first turn about each axis.

    Raises ProtocolError naming the missing stage and saying how to record it.
    """
    stages = sorted(stages, key=lambda s: s.start)
    turns = [s for s in stages if s.kind == "turn" and s.axis is not None]
    stills = [s for s in stages if s.kind == "still"]
    chosen: dict[str, Stage] = {}
    notes: list[str] = []
    for s in turns:
        assert s.axis is not None
        if s.axis in chosen:
            notes.append(
                f"the device was turned about {s.axis} more than once; the first turn "
                f"(at {chosen[s.axis].start_s:.1f} s) is used, not the one at {s.start_s:.1f} s"
            )
        else:
            chosen[s.axis] = s
    missing = [a for a in AXES if a not in chosen]
    if missing:
        found = ", ".join(f"about {s.axis} at {s.start_s:.1f} s" for s in chosen.values())
        n_motion = sum(s.kind == "motion" for s in stages)
        detail = (f" Turns found: {found}." if found else " No full turn was found at all.") + (
            f" {n_motion} other motion(s) were not full turns: a turn counts when it is one full turn"
            f" ({StageConfig.min_turn_deg:.0f}-{StageConfig.max_turn_deg:.0f} degrees as measured) about one device axis,"
            " between two pauses."
            if n_motion else ""
        )
        if stages and stages[0].kind == "motion" and stages[0].start == 0:
            detail += (f" The recording begins in motion (0-{stages[0].duration_s:.1f} s), so a turn there has no pause"
                       " before it: start recording with the device at rest.")
        if len(stages) > 1 and stages[-1].kind == "motion":
            detail += (" The recording ends in motion, so a turn there has no pause after it: keep the device still"
                       " for about 3 s after the last turn before stopping.")
        if len(missing) == 1:
            a = missing[0]
            msg = f"no turn about {a} was found: turn the device a full 360 degrees about its {a} axis, {_TURN_HOWTO} the turn."
        else:
            names = " or ".join(missing)
            msg = (f"no turn about {names} was found: turn the device a full 360 degrees about each of its "
                   f"{', '.join(missing)} axes, {_TURN_HOWTO} each turn.")
        raise ProtocolError(msg + detail, code="turn_missing", stages=stages)
    first = min(chosen.values(), key=lambda s: s.start)
    before = [s for s in stills if s.end <= first.start and s.duration_s >= min_still0_s]
    if not before:
        raise ProtocolError(
            f"no still segment of at least {min_still0_s:g} s before the first turn (about {first.axis} at "
            f"{first.start_s:.1f} s) was found: put the device down and keep it still for about 3 s before turning it.",
            code="still_missing", stages=stages,
        )
    still0 = before[-1]
    order = sorted(chosen, key=lambda a: chosen[a].start)
    if order != list(AXES):
        notes.append(f"the turns were made in the order {', '.join(order)} (the protocol order is x, y, z)")
    if stages.index(still0) != stages.index(first) - 1:
        notes.append(
            f"the still just before the first turn is shorter than {min_still0_s:g} s; the still at "
            f"{still0.start_s:.1f}-{still0.end_s:.1f} s is used as the first still"
        )
    for a in AXES:
        if chosen[a].flags:
            notes.append(f"the turn about {a} is flagged: {', '.join(chosen[a].flags)}")
    if still0.flags:
        notes.append(f"the first still is flagged: {', '.join(still0.flags)}")
    return ProtocolStages(still0=still0, turns={a: chosen[a] for a in AXES}, stills=stills, notes=notes)
