"""The guided session's rules as pure functions: judging a closed motion, and the protocol's time limits."""

from __future__ import annotations

import numpy as np
import pytest

from calib.judge.acceptance import Tolerances
from server.config import ProtocolTimings
from server.live.codes import EndReason, Phase, State
from server.live.time_limits import overdue
from server.live.turn_judge import TurnMeasure, is_no_turn, judge_turn

TOL = Tolerances()
TM = ProtocolTimings()


def measure(angles, saturated=False, lost=0, gravity=None) -> TurnMeasure:
    return TurnMeasure(np.asarray(angles, dtype=float), saturated, lost, gravity)


def test_a_full_turn_about_the_asked_axis_passes_either_way():
    assert judge_turn("y", measure([3.0, 361.0, -5.0], gravity=1.0), TOL, None, True) is None
    assert judge_turn("z", measure([0.0, 2.0, -358.0]), TOL, None, True) is None


@pytest.mark.parametrize(
    ("angles", "extra", "code", "words"),
    [
        ([360.0, 0, 0], {"lost": 4}, EndReason.SAMPLE_LOSS, "4"),
        ([360.0, 0, 0], {"saturated": True}, EndReason.TOO_FAST, "more slowly"),
        ([0, 360.0, 0], {}, EndReason.WRONG_AXIS, "Y"),
        ([250.0, 0, 0], {}, EndReason.TURN_INCOMPLETE, "250"),
        ([500.0, 0, 0], {}, EndReason.TURN_TOO_FAR, "500"),
        ([330.0, 130.0, 0], {}, EndReason.WRONG_AXIS, ""),
        ([360.0, 0, 0], {"gravity": 30.0}, EndReason.TURN_INCOMPLETE, "30"),
    ],
)
def test_each_way_a_turn_can_go_wrong_is_named(angles, extra, code, words):
    got = judge_turn("x", measure(angles, **extra), TOL, 250.0, True)
    assert got is not None
    assert got[0] == code
    assert words.lower() in got[1].lower()


def test_lost_samples_outrank_every_other_problem():
    got = judge_turn("x", measure([0, 100.0, 0], saturated=True, lost=2), TOL, 250.0, False)
    assert got is not None and got[0] == EndReason.SAMPLE_LOSS


def test_a_fidget_is_no_turn():
    assert is_no_turn(np.array([20.0, -5.0, 3.0]), TOL)
    assert not is_no_turn(np.array([200.0, 0.0, 0.0]), TOL)


def test_time_limits_hint_once_then_fail():
    assert overdue(State.STILL, Phase.WAITING, None, TM.hint_after_s - 1, False, TM, True) is None
    hint = overdue(State.STILL, Phase.WAITING, None, TM.hint_after_s + 1, False, TM, True)
    assert hint is not None and hint.action == "hint"
    assert overdue(State.STILL, Phase.WAITING, None, TM.hint_after_s + 1, True, TM, True) is None
    fail = overdue(State.STILL, Phase.WAITING, None, TM.fail_after_s + 1, True, TM, True)
    assert fail is not None and (fail.action, fail.code) == ("fail", EndReason.NOT_STILL)
    ready = overdue(State.TURN_Y, Phase.READY, "y", TM.fail_after_s + 1, True, TM, True)
    assert ready is not None and (ready.action, ready.code) == ("fail", EndReason.NO_MOTION)


def test_a_turn_too_long_is_retried_and_a_drifting_pause_fails():
    long = overdue(State.TURN_X, Phase.TURNING, "x", TM.max_turn_s + 1, False, TM, True)
    assert long is not None and (long.action, long.code) == ("retry", EndReason.TURN_TOO_LONG)
    assert overdue(State.TURN_X, Phase.TURNING, "x", TM.max_turn_s - 1, False, TM, True) is None
    pause = overdue(State.TURN_Z, Phase.PAUSE, "z", TM.fail_after_s + 1, False, TM, True)
    assert pause is not None and (pause.action, pause.code) == ("fail", EndReason.MOVED_DURING_PAUSE)
