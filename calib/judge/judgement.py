"""Judging a calibration, once for every door: its tolerance checks, its departures from the device's own history,
and how far a full turn read from 360° before and after it. A live session and an uploaded recording are judged by
the same ``judge``."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from calib.judge.acceptance import Check, Tolerances, evaluate, turn_accuracy
from calib.judge.departure import Departure, departures
from calib.result import CalibrationResult


@dataclass(frozen=True)
class Judgement:
    """What the operator is shown before Accept: every check, the departures, the turns' accuracy."""

    checks: tuple[Check, ...]
    departures: tuple[Departure, ...]
    accuracy: dict[str, Any] | None  # the worst turn's distance from 360° before and after (acceptance.turn_accuracy)

    @property
    def failures(self) -> list[str]:
        """The sentences of the checks that failed."""
        return [c.text for c in self.checks if not c.ok]

    @property
    def failed_checks(self) -> list[Check]:
        """The checks that failed."""
        return [c for c in self.checks if not c.ok]

    @property
    def passed(self) -> bool:
        """Every check passed (departures are cautions, not failures)."""
        return not self.failures

    def checks_json(self) -> list[dict[str, Any]]:
        """The checks in their JSON form."""
        return [c.to_dict() for c in self.checks]

    def departures_json(self) -> list[dict[str, Any]]:
        """The departures in their JSON form."""
        return [d.to_dict() for d in self.departures]


def judge(result: CalibrationResult, tolerances: Tolerances, history: Sequence[dict[str, Any]] = ()) -> Judgement:
    """``result`` judged against ``tolerances`` and the device's earlier calibrations ``history`` (their JSON form,
    newest first: the first is the one in force until now, which the turns' accuracy compares with)."""
    doc = result.to_dict()  # departures and the turns' accuracy read the same JSON form: made once
    in_force = history[0] if history else None
    return Judgement(tuple(evaluate(result, tolerances)), tuple(departures(doc, history)), turn_accuracy(doc, in_force))
