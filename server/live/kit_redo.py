"""Whether a kit's calibration asks its tray for a turn again, as one wearable's does (server.live.session).

Alone, a result out of range on a scale factor, or whose turns cannot close, asks again the turn that most likely was
not a full one (a turn about the vertical that stopped short, or went on too far, leaves gravity where it was, so only
the calibration can tell). In a kit the tray is turned for every wearable at once: it is asked a turn again only when
every wearable's result failed and points to that turn. One wearable's failure alone is its own (its sensor, or its
seat in the tray), and the others' results stand.
"""

from __future__ import annotations

from collections.abc import Mapping, Set

from calib.judge.acceptance import Tolerances
from calib.judge.judgement import judge
from calib.stages.stage import AXES

from ..workers.compute import LiveOutcome
from . import guidance as say


def tray_turns_to_redo(outcomes: Mapping[str, LiveOutcome], tolerances: Mapping[str, Tolerances],
                       asked_before: Set[str]) -> list[str]:
    """The turns (axes, in protocol order) every wearable's result points to, none asked again before; empty when any
    wearable has no result, passed, or points elsewhere."""
    pointed: list[set[str]] = []
    for name, outcome in outcomes.items():
        if outcome.result is None:
            return []
        judgement = judge(outcome.result, tolerances[name], [])
        if judgement.passed:
            return []
        pointed.append(set(say.turns_to_redo(judgement.failed_checks)))
    common = set.intersection(*pointed) if pointed else set()
    return [a for a in AXES if a in common and a not in asked_before]
