"""Whether a kit's calibration asks its tray for a turn again, as one wearable's does (server.live.session).

Alone, a result out of range on a scale factor, or whose turns cannot close, asks again the turn that most likely was
not a full one (a turn about the vertical that stopped short, or went on too far, leaves gravity where it was, so only
the calibration can tell). The tray is turned for every wearable at once, so in a kit:
- a scale factor out of range on any wearable asks the tray that turn again: the turn was short or long for all, and
  the others' scale factors, in range, took it as a full turn; or that sensor reads out of range, and once asked
  again it says so as alone (the others' results are only the better for the new turn);
- a turn that cannot close asks it again only when every wearable's result failed and points to it: one wearable's
  turn that does not close while the others' do is its own (its readings, or its seat in the tray).
"""

from __future__ import annotations

from collections.abc import Mapping, Set

from calib.judge.acceptance import Tolerances
from calib.judge.judgement import judge
from calib.stages.stage import AXES

from ..workers.compute import LiveOutcome
from . import guidance as say


def tray_turns_to_redo(outcomes: Mapping[str, LiveOutcome], tolerances: Mapping[str, Tolerances],
                       asked_before: Set[str]) -> tuple[list[str], list[str]]:
    """The turns (axes, in protocol order) to ask the tray again, none asked again before (see the module), and the
    wearables whose scale factor out of range asks them (empty: every wearable's result points to them)."""
    judged = {name: judge(o.result, tolerances[name], []) for name, o in outcomes.items() if o.result is not None}
    out_of_range = {name: set(say.scale_factor_turns(j.failed_checks)) - asked_before for name, j in judged.items()}
    by = [name for name, axes in out_of_range.items() if axes]
    if by:
        every = len(by) == len(outcomes)  # then said of every wearable, not as some against the others
        return [a for a in AXES if any(a in out_of_range[n] for n in by)], [] if every else by
    if judged and len(judged) == len(outcomes) and not any(j.passed for j in judged.values()):
        common = set.intersection(*(set(say.turns_to_redo(j.failed_checks)) for j in judged.values()))
        return [a for a in AXES if a in common and a not in asked_before], []
    return [], []
