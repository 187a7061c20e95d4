"""Whose fault a kit's wearable saw in a turn or its pause: the tray's, or its own.

Turned together, the kit's wearables see one motion, but each checks it on its own readings: one with a smaller range
clips a fast turn the others read whole, one with an older calibration finds a turn short that the others find full,
one loose in its slot moves in a pause while the tray stays still. A fault is the tray's when every wearable at that
turn saw one: the tray is turned again (each wearable's own try, as alone). One the rest of the kit did not see is
that wearable's own: the tray is not turned again for it, and the kit's calibration closes that turn from the others'
readings of it. A wearable never asks a turn again alone, so it never falls behind the tray and is never failed for
a turn it judged against a step the tray had left.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Protocol

from .codes import STEPS, Phase, State
from .turn_checks import HeldFault

HOLD_S = 0.5  # device time a wearable's fault waits for the others' readings of the same moment (a knock reaches
# each wearable's detector up to a few tenths of a second apart) before another's passing that turn makes it its own
WAIT_S = 2.0  # ... and at most this long for the verdicts of those still checking that turn
AT_THE_TURN = frozenset({Phase.TURNING, Phase.PLACING, Phase.CHECKING, Phase.PAUSE})
NOT_FOLLOWING = frozenset({State.CONNECTING, State.RECONNECTING})


class Wearable(Protocol):
    """What the judgement uses of a kit wearable's guided session (server.live.session.GuidedSession)."""

    device_id: str
    state: State
    phase: Phase | None
    held_fault: HeldFault | None
    t_now: float

    @property
    def turns(self) -> Mapping[str, object]: ...

    @property
    def axis(self) -> str | None: ...

    @property
    def finished(self) -> bool: ...

    def release_held(self) -> None: ...

    def kit_closes_turn(self, passed: list[str]) -> None: ...


def _step(w: Wearable) -> int:
    return STEPS.index(w.state) if w.state in STEPS else 0


def judge_held(wearables: Sequence[Wearable]) -> bool:
    """Judge every held fault that can be judged now; True while some stay held (judge again shortly)."""
    following = [w for w in wearables if not w.finished and w.state not in NOT_FOLLOWING]
    for w in following:
        held = w.held_fault
        if held is None:
            continue
        at_turn = [o for o in following if o.state == w.state and o.phase in AT_THE_TURN]
        # past this turn, or in the pause after it with the turn recorded (one whose fault the kit closed rests there
        # without it), in the kit's order
        passed = [o for o in following if _step(o) > _step(w)
                  or (o in at_turn and o.held_fault is None and o.phase == Phase.PAUSE and w.axis in o.turns)]
        undecided = [o for o in at_turn if o.held_fault is None and o.phase != Phase.PAUSE]
        if not passed and not undecided:  # every wearable at this turn saw a fault: the tray's
            for o in at_turn:
                o.release_held()
        elif passed and w.t_now - held.at_t >= (WAIT_S if undecided else HOLD_S):
            w.kit_closes_turn([o.device_id for o in passed])
    return any(w.held_fault is not None for w in following)
