"""A kit as a restarted service shows it: composed from what the store kept of its wearables' sessions, by the same
rule as a running kit (server.live.kit_snapshot)."""

from __future__ import annotations

from pathlib import Path

from calib.result import CalibrationResult
from server.live.kit_snapshot import stored_kit_snapshot
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
