"""A late service is never the clinician's fault: data that arrives late but complete carries the session on where it
was; only samples that are missing (by sequence and device clock) count as a lost link; the time the service itself
did not run is said, and not counted against the wall-clock limits."""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path

import pytest
from server_fixtures import RunningService, wait_for
from test_server_session import FS, STANDARD, Run, sim

from server.config import Settings


class Clock:
    """The session's wall clock, moved by hand."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def _mid_y_turn() -> int:
    i = int((3.5 + 3 + 3 + 1.5) * FS)
    return i - i % 3


def test_late_complete_data_keeps_the_turn_in_progress() -> None:
    rec, _ = sim(STANDARD)
    clock = Clock()
    run = Run(max_attempts=3, clock=clock)
    i = _mid_y_turn()
    run.feed(rec, 0, i)
    assert run.s.state == "turn_y" and run.s.phase == "turning"
    clock.now += 4.0
    run.s.data_silent(4.0)  # the watchdog saw no data for 4 s ...
    clock.now += 3.0
    run.s.data_resumed(lost=0)  # ... then it came, complete: it was late, not lost
    run.feed(rec, i)
    assert run.s.state == "computing", run.s.reason
    assert run.warnings() == ["no_data", "data_resumed"]
    assert "nothing was lost" in run.s.warnings[-1].message
    assert run.s.attempt == 1 and run.s.lost_samples == 0


def test_data_missing_after_a_silence_is_a_lost_link_and_the_turn_is_done_again() -> None:
    rec, _ = sim(STANDARD)
    run = Run(max_attempts=3)
    i = _mid_y_turn()
    run.feed(rec, 0, i)
    run.s.data_silent(3.0)
    run.s.data_resumed(lost=40)
    assert run.warnings() == ["no_data", "link_lost", "link_restored"]
    assert run.s.state == "turn_y" and run.s.phase == "settle"
    assert "The turn about Y will be done again" in run.s.warnings[-1].message


def test_the_service_s_own_lateness_is_said_and_not_counted_against_the_limits() -> None:
    rec, _ = sim(STANDARD)
    clock = Clock()
    settings = Settings(db_url="sqlite://", session_timeout_s=60.0, service_late_limit_s=300.0)
    run = Run(settings=settings, max_attempts=3, clock=clock)
    i = _mid_y_turn()
    run.feed(rec, 0, i)
    clock.now += 70.0  # the process was stopped for 70 s: past the session's own 60 s limit on the wall clock
    run.s.service_was_late(70.0)
    run.s.tick()
    assert not run.s.finished
    assert run.warnings() == ["service_late"] and "fell 70.0 s behind" in run.s.warnings[-1].message
    run.feed(rec, i)
    assert run.s.state == "computing", run.s.reason
    assert run.s.snapshot().service_late_s == 70.0


def test_a_service_late_beyond_its_limit_ends_with_a_reason_of_its_own() -> None:
    rec, _ = sim(STANDARD)
    run = Run(settings=Settings(db_url="sqlite://", service_late_limit_s=30.0), max_attempts=3, clock=Clock())
    run.feed(rec, 0, _mid_y_turn())
    run.s.service_was_late(20.0)
    assert not run.s.finished
    run.s.service_was_late(15.0)
    assert run.s.state == "failed" and run.s.reason_code == "service_overloaded"
    assert "not the wearable, nor the way the device was turned" in run.s.reason


CLINICIAN_REASONS = {"not_still", "no_motion", "moved_during_pause", "wrong_axis", "too_fast", "turn_incomplete",
                     "turn_too_far", "turn_too_long"}


def _stall(proc: subprocess.Popen[str], seconds: float) -> None:
    """Stop the service's process (no CPU at all) for ``seconds``, then let it run on."""
    proc.send_signal(signal.SIGSTOP)
    try:
        time.sleep(seconds)
    finally:
        proc.send_signal(signal.SIGCONT)


@pytest.mark.timeout(240)
def test_a_service_stalled_mid_turn_at_real_speed_fails_no_session_on_the_clinician(tmp_path: Path) -> None:
    """Four scripted wearables at real speed; the service's process is stopped for 3 s in the middle of the x turns
    and again for 2.5 s in the y turns. The hands do not wait for prompts (they turn when their script says), so a
    turn the service threw away would never come again. Every session must end done, say the service was late, and
    never say the link was lost."""
    svc = RunningService(["--mock", "4"], f"sqlite:///{tmp_path / 'store.sqlite3'}").start()
    try:
        assert svc.proc is not None
        with svc.client() as c:
            sids = [c.post(f"/devices/mock-{i}/calibrate").json()["session_id"] for i in range(1, 5)]

            def phases() -> list[tuple[str, str | None]]:
                snaps = [c.get(f"/sessions/{sid}").json() for sid in sids]
                return [(s["state"], s.get("phase")) for s in snaps]

            for state in ("turn_x", "turn_y"):
                wait_for(lambda state=state: any(p == (state, "turning") for p in phases()), 60, f"a {state} in progress")
                _stall(svc.proc, 3.0 if state == "turn_x" else 2.5)

            def all_ended() -> list[dict] | None:
                snaps = [c.get(f"/sessions/{sid}").json() for sid in sids]
                return snaps if all(s["state"] in ("done", "failed", "cancelled") for s in snaps) else None

            ended = wait_for(all_ended, 120, "every session's end")
    finally:
        svc.stop()
    outcomes = {s["device_id"]: (s["state"], s["reason_code"], [w["code"] for w in s["warnings"]]) for s in ended}
    assert not {d: o for d, o in outcomes.items() if o[1] in CLINICIAN_REASONS}, outcomes
    assert all(o[0] == "done" for o in outcomes.values()), outcomes
    assert all("service_late" in o[2] for o in outcomes.values()), outcomes
    assert not any("link_lost" in o[2] for o in outcomes.values()), outcomes
    assert all(s["lost_samples"] == 0 and s["service_late_s"] >= 2.0 for s in ended), outcomes
