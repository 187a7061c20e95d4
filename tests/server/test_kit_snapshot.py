"""A kit as a restarted service shows it: composed from what the store kept of its wearables' sessions, by the same
rule as a running kit (server.live.kit_snapshot)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from pathlib import Path

from calib.judge.acceptance import Check
from calib.result import CalibrationResult
from server.live import guidance as say
from server.live.kit_snapshot import kit_snapshot, kit_warnings, stored_kit_snapshot
from server.live.snapshot_schema import KitOut, SessionOut, SessionWarning
from server.store import SessionEnd, Store

RESULT = CalibrationResult.from_dict({"k": [1.01, 0.99, 1.02], "b": [0.5, -0.25, 0.125], "method": "kit-closure",
                                      "uncertainty": {"k": [1e-4] * 3, "b": [1e-3] * 3}, "stages": []})
MEMBERS = {"mock-1": "a" * 32, "mock-2": "b" * 32, "mock-3": "c" * 32}


def _kit(tmp_path: Path) -> Store:
    store = Store(f"sqlite:///{tmp_path / 'store.sqlite3'}")
    for device_id, sid in MEMBERS.items():
        store.create_session(sid, device_id, "live", "connecting", "closure", "alice", "0.1.0")
    store.create_kit("k" * 32, "alice", MEMBERS)
    return store


def test_a_kit_cut_off_by_a_restart_shows_failed_naming_each_wearable_and_why(tmp_path: Path) -> None:
    store = _kit(tmp_path)
    store.fail_unfinished_sessions("The service restarted during the calibration.")
    snap = stored_kit_snapshot(*store.kit("k" * 32))
    assert snap.kind == "kit" and snap.state == "failed" and snap.session_id == "k" * 32 and snap.operator == "alice"
    assert snap.reason_code == "service_restarted"
    assert [(d.device_id, d.state) for d in snap.devices] == [(d, "failed") for d in MEMBERS]
    assert all(f"{d}: The service restarted" in snap.reason for d in MEMBERS), snap.reason
    assert snap.passed is None and snap.decision is None


def test_a_kit_that_ended_shows_who_passed_who_departed_and_the_decision(tmp_path: Path) -> None:
    store = _kit(tmp_path)
    for device_id in ("mock-1", "mock-2"):
        store.finish_session(MEMBERS[device_id], SessionEnd("done", result=RESULT, passed=device_id == "mock-1"))
    store.finish_session(MEMBERS["mock-3"], SessionEnd("failed", "departed", "The wearable came apart from the kit."))
    store.record_kit_outcome("k" * 32, None, ["mock-3"], None)
    snap = stored_kit_snapshot(*store.kit("k" * 32))
    assert snap.state == "done" and snap.passed and snap.kit is not None and snap.kit.departed == ["mock-3"]
    assert [(d.state, d.passed, d.departed) for d in snap.devices] == [("done", True, False), ("done", False, False),
                                                                       ("failed", None, True)]
    assert snap.devices[0].result is not None and snap.reason == "mock-3: The wearable came apart from the kit."
    store.accept(MEMBERS["mock-1"], "alice")
    assert stored_kit_snapshot(*store.kit("k" * 32)).decision == "accepted"


def test_a_kit_wearables_reasons_say_the_tray_for_what_the_hand_did_and_the_wearable_for_itself(tmp_path: Path) -> None:
    # on the kit page the clinician's hands held the tray: a wearable's own reason must not send her to "the device"
    # for the rest or the turns, yet must still name the wearable for its link and its sensor
    store = _kit(tmp_path)
    bias = Check(name="b", axis="y", value=9.0, limit=5.0, ok=False, text="b_y 9.000 deg/s is over 5 deg/s",
                 used=1.8, near_limit=False)
    reasons = {
        "mock-1": ("out_of_tolerance", say.out_of_tolerance([bias], failed_before=[("b", "y")])),
        "mock-2": ("link_lost", say.link_lost(60.0)),
        "mock-3": ("moved_during_pause", say.moved_during_pause("x", 3.0, retry=False, turn_recorded=True)),
    }
    for device_id, (code, reason) in reasons.items():
        store.finish_session(MEMBERS[device_id], SessionEnd("failed", code, reason))
    snap = stored_kit_snapshot(*store.kit("k" * 32))
    rows = {d.device_id: d.reason or "" for d in snap.devices}
    assert "Check that the tray rested against the block" in rows["mock-1"], rows["mock-1"]
    assert rows["mock-1"].endswith("the sensor may be faulty; have the wearable checked."), rows["mock-1"]
    assert rows["mock-2"].startswith("The connection to the wearable was lost and did not come back within 60 s. Check "
                                     "that the wearable is switched on"), rows["mock-2"]
    assert rows["mock-3"].startswith("The tray moved during the pause after the turn about X."), rows["mock-3"]
    assert "keep the tray still against the block" in rows["mock-3"], rows["mock-3"]
    assert not any("device" in r for r in rows.values()), rows
    assert snap.reason is not None and "device" not in snap.reason and "mock-3: The tray moved" in snap.reason
    # a kit its estimator refused: its words, of the tray
    store.record_kit_outcome("k" * 32, None, [], "The kit could not be calibrated together: no turn about Z was found: "
                             "turn the device a full 360 degrees about its Z axis. Start a new calibration.")
    refused = stored_kit_snapshot(*store.kit("k" * 32)).kit
    assert refused is not None and refused.refusal is not None and "turn the tray a full 360 degrees" in refused.refusal


def _wearable(device_id: str, *warnings: tuple[str, str, float]) -> SessionOut:
    """A running wearable's snapshot with its warnings: (code, message, seconds after 12:00)."""
    at = datetime(2026, 5, 4, 12, 0, tzinfo=UTC)
    return SessionOut(session_id=device_id * 4, device_id=device_id, state="turn_y", warnings=[
        SessionWarning(code=c, message=m, t_device_s=s, at=(at + timedelta(seconds=s)).isoformat()) for c, m, s in warnings])


def test_the_kit_says_the_trays_warnings_once_and_names_a_wearables_own() -> None:
    moved, late = say.MOVED_RESTART, say.service_late(1.2)
    wrong = say.wrong_axis("y", "x", retry=True)
    snaps = [
        _wearable("mock-1", ("moved", moved, 1.0), ("wrong_axis", wrong, 9.0), ("moved", moved, 10.5)),
        _wearable("mock-2", ("moved", moved, 1.02), ("no_data", say.no_data(3.0), 4.0), ("link_restored", say.link_restored("y"), 6.0),
                  ("wrong_axis", wrong, 9.01), ("service_late", say.service_late(1.3), 12.01)),
        _wearable("mock-3", ("moved", moved, 1.01), ("wrong_axis", wrong, 9.02), ("service_late", late, 12.0),
                  ("sample_loss", say.sample_loss("z", 12, retry=True), 15.0)),
    ]
    said = [(w.code, w.message) for w in kit_warnings(snaps)]
    assert said == [
        ("moved", "The tray moved: the count starts again. Keep it still against the block."),  # one bump, three wearables
        ("no_data", "mock-2: No data from the wearable for 3 s. Keep it still and close to the receiver: the session "
                    "carries on as soon as its data arrives."),
        ("link_restored", "Reconnected to mock-2: the kit goes on."),  # the tray is not turned again for one wearable
        ("wrong_axis", "That turn was about X, not Y. Put the tray back against the block, wait for the prompt and turn "
                       "again about Y. Turn about the Y axis marked on the case."),
        ("moved", "The tray moved: the count starts again. Keep it still against the block."),  # a second bump
        ("service_late", "The calibration service fell 1.2 s behind (the computer running it is busy). It is catching "
                         "up with the data it received: nothing was lost, and nothing needs to be done again."),
        ("sample_loss", "mock-3 lost samples on the radio link during a turn. The kit goes on: that turn of mock-3 is "
                        "closed with the other wearables'."),  # not "turn again": the tray is not turned for one
    ]
    # a warning that comes later comes last: the page counts what it has seen
    snaps[2].warnings.append(SessionWarning(code="moved", message=moved, t_device_s=20.0, at="2026-05-04T12:00:20+00:00"))
    assert [(w.code, w.message) for w in kit_warnings(snaps)] == [*said, said[0]]


def test_the_tray_follows_the_wearables_that_went_on_not_one_that_asks_a_turn_again() -> None:
    """mock-1 asks the turn about X again (its sensor alone saw a fault) while mock-2 rests after it: the tray is not
    turned again for one wearable, so the kit's prompt is mock-2's. When every wearable asks again, the tray does."""
    def at(device_id: str, phase: str, attempt: int, prompt: str) -> SessionOut:
        return SessionOut(session_id=device_id * 4, device_id=device_id, state="turn_x", phase=phase, axis="x",
                          attempt=attempt, max_attempts=3, prompt=prompt)

    again, rests = say.PROMPTS["settle"], say.pause_prompt("x", "y")
    kit = kit_snapshot("k" * 32, [at("mock-1", "settle", 2, again), at("mock-2", "pause", 1, rests)], KitOut(),
                       operator="alice", started_at=None, cancelled=False)
    assert (kit.state, kit.phase, kit.attempt) == ("turn_x", "pause", 1)
    assert kit.prompt == "Turn about X recorded. Keep the tray still against the block before the turn about Y."
    kit = kit_snapshot("k" * 32, [at("mock-1", "settle", 2, again), at("mock-2", "settle", 2, again)], KitOut(),
                       operator="alice", started_at=None, cancelled=False)
    assert (kit.phase, kit.attempt, kit.prompt) == ("settle", 2, "Put the tray back against the block and keep it still.")
