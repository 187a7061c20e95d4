"""A whole kit in one guided session, through the real service (`gyrocal serve --mock N --mock-kit`): the simulated
wearables ride in one tray that one clinician turns; the kit holds every wearable, names the one that slipped in its
slot, bridges the one whose link dropped, and stores every wearable that passed in one transaction."""

from __future__ import annotations

import time

import httpx
import numpy as np

from tests.server_fixtures import RunningService, at_once, follow_events, kit_through_the_command_line

SPEED = "6"


def _until_ended(c: httpx.Client, kit_id: str, timeout_s: float = 90.0) -> dict:
    deadline = time.monotonic() + timeout_s
    seen: list[str] = []
    while time.monotonic() < deadline:
        snap = c.get(f"/sessions/{kit_id}").json()
        if not seen or seen[-1] != snap["state"]:
            seen.append(snap["state"])
        if snap["state"] in ("done", "failed", "cancelled"):
            snap["seen"] = seen
            return snap
        time.sleep(0.25)
    raise AssertionError(f"the kit did not end within {timeout_s} s; it went through {seen}")


def _truth(c: httpx.Client, device_id: str) -> np.ndarray:
    return np.array(c.get(f"/devices/{device_id}").json()["simulated_truth"]["k"])


def test_a_kit_is_guided_as_one_the_loose_wearable_is_named_and_the_rest_are_accepted_at_once(postgres, tmp_path) -> None:
    """On PostgreSQL (the store's own test holds the accept's one transaction on SQLite too). The recordings the
    service kept give the same calibration through `gyrocal calibrate-kit`; the kit is accepted after the service
    restarted, from what the store kept."""
    url = postgres.service_url(postgres.create_database())
    svc = RunningService(["--mock", "4", "--mock-kit", "--mock-kit-loose", "3", "--mock-speed", SPEED], url).start(60)
    try:
        with svc.client() as c:
            kit_a = {"devices": ["mock-1", "mock-2", "mock-3"]}
            kit_b = {"devices": ["mock-3", "mock-4"]}  # shares mock-3: of the two asked for at once, one is refused
            first, second = at_once([lambda: c.post("/kits/calibrate", json=kit_a), lambda: c.post("/kits/calibrate", json=kit_b)])
            assert sorted([first.status_code, second.status_code]) == [202, 409], (first.text, second.text)
            started, refused = (first, second) if first.status_code == 202 else (second, first)
            assert "mock-3" in refused.json()["detail"] and "leave it out of the kit" in refused.json()["detail"]
            if started is second:  # kit B won the race: let it end, then start kit A
                assert c.post(f"/kits/{started.json()['session_id']}/cancel").status_code == 200
                started = c.post("/kits/calibrate", json=kit_a)
                assert started.status_code == 202, started.text
            kit_id = started.json()["session_id"]
            assert started.headers["location"] == f"/sessions/{kit_id}"
            members = {d["device_id"]: d["session_id"] for d in started.json()["devices"]}
            assert list(members) == ["mock-1", "mock-2", "mock-3"]
            # while the kit runs, each of its wearables is held
            assert c.post("/devices/mock-2/calibrate", json={}).status_code == 409
            assert c.post(f"/sessions/{kit_id}/accept").status_code == 409
            snap = _until_ended(c, kit_id)
            assert snap["kind"] == "kit" and snap["state"] == "done"
            # the kit went forward through the protocol (which steps a poll catches depends on the machine's load)
            steps = ["connecting", "still", "turn_x", "turn_y", "turn_z", "computing", "done"]
            assert [steps.index(s) for s in snap["seen"]] == sorted(steps.index(s) for s in snap["seen"]), snap["seen"]
            assert any(s.startswith("turn_") for s in snap["seen"]), snap["seen"]
            devices = {d["device_id"]: d for d in snap["devices"]}
            assert snap["kit"]["departed"] == ["mock-3"]
            assert devices["mock-3"]["state"] == "failed" and devices["mock-3"]["departed"]
            # its own words, once: not "the calibration could not be computed", nor a second instruction after its own
            assert devices["mock-3"]["reason_code"] == "departed", devices["mock-3"]
            # (it slipped in a turn: how far is not said, as its own k absorbs part of it)
            assert devices["mock-3"]["reason"] == ("The wearable came apart from the kit: it moved in its slot, or its "
                                                   "readings do not follow the tray. Seat it firmly in its slot, then "
                                                   "calibrate it alone or with the kit.")
            assert snap["reason"] == f"mock-3: {devices['mock-3']['reason']}"
            consistency = snap["kit"]["consistency"]["devices"]
            assert consistency["mock-3"]["departed"] and consistency["mock-3"]["angle_deg"] > 0.2
            axes = snap["kit"]["consistency"]["axes"]  # the simulated sensors' axes are orthogonal: a diagonal K each
            assert axes["model"] == "diagonal" and axes["dof"] == 3 and "agree" in axes["reason"], axes
            for name in ("mock-1", "mock-2"):
                d = devices[name]
                assert d["state"] == "done" and d["passed"], d["reason"]
                result = d["result"]
                assert result["method"] == "kit-closure" and result["quality"]["kit"]["devices"] == 2
                k, std = np.array(result["k"]), np.array(result["uncertainty"]["k"])
                assert np.all(np.abs(k - _truth(c, name)) < 5 * std + 2e-5), (k - _truth(c, name)) / std
                own = c.get(f"/sessions/{members[name]}").json()  # each wearable's own session holds its result too
                assert own["state"] == "done" and own["result"]["k"] == result["k"]
            # one door: the recordings and section lists the service kept give the same through the command line
            cli = kit_through_the_command_line(c, members, tmp_path)
            assert cli["kit"]["departed"] == ["mock-3"], cli["kit"]
            by_name = {d["device_id"]: d["result"] for d in cli["devices"]}
            assert all((by_name[n]["k"], by_name[n]["b"]) == (devices[n]["result"]["k"], devices[n]["result"]["b"])
                       for n in ("mock-1", "mock-2")), by_name
        svc.stop()  # the kit outlives its service: restarted on the same store, it shows the same and is accepted there
        svc.start(60)
        with svc.client() as c:
            again = c.get(f"/sessions/{kit_id}").json()
            assert again["kind"] == "kit" and again["state"] == "done" and again["kit"] == snap["kit"]
            assert [(d["device_id"], d["session_id"], d["state"], d["passed"], d["departed"], d["result"]) for d in again["devices"]] \
                == [(d["device_id"], d["session_id"], d["state"], d["passed"], d["departed"], d["result"]) for d in snap["devices"]]
            assert c.get(f"/kits/{kit_id}").json() == again
            # the device list leads each wearable that passed back to the kit, whose accept saves them all at once
            listed = {d["id"]: d for d in c.get("/devices").json()}
            assert [(listed[n]["unsaved_session"], listed[n]["unsaved_kit"]) for n in ("mock-1", "mock-2", "mock-3")] \
                == [(members["mock-1"], kit_id), (members["mock-2"], kit_id), (None, None)]
            assert c.post(f"/kits/{kit_id}/cancel").status_code == 409
            # two operators press "Accept all that passed" at once: one stores the kit, the other is told it was decided
            both = at_once([lambda: c.post(f"/kits/{kit_id}/accept"), lambda: c.post(f"/kits/{kit_id}/accept")])
            assert sorted(r.status_code for r in both) == [200, 409], [r.text for r in both]
            accepted = next(r for r in both if r.status_code == 200)
            # (in the clinician's words, naming the wearable, not a session id; which sentence depends on whether the
            # other request was still storing or had stored)
            refused = next(r for r in both if r.status_code == 409).json()["detail"]
            assert "mock-1" in refused and "already" in refused and "session " not in refused, refused
            body = accepted.json()
            assert [r["device_id"] for r in body["calibrations"]] == ["mock-1", "mock-2"]
            assert "came apart" in body["not_accepted"]["mock-3"]
            for r in body["calibrations"]:
                current = c.get(f"/devices/{r['device_id']}/calibration").json()
                assert current["id"] == r["id"] and current["method"] == "kit-closure"
            audit = c.get("/audit", params={"limit": 50}).json()
            accepts = [e for e in audit if e["action"] == "calibration.accept"]
            assert sorted(e["device_id"] for e in accepts) == ["mock-1", "mock-2"]
            assert c.post(f"/kits/{kit_id}/accept").status_code == 409  # decided already
            assert c.get(f"/sessions/{kit_id}").json()["decision"] == "accepted"
            assert c.get("/devices/mock-3/calibration").status_code == 404  # the loose one keeps what it had: nothing
            # the loose wearable is free again: it can be redone alone
            alone = c.post("/devices/mock-3/calibrate", json={})
            assert alone.status_code == 202, alone.text
            assert c.post(f"/sessions/{alone.json()['session_id']}/cancel").status_code == 200
    finally:
        svc.stop()


def test_a_wearable_whose_link_drops_mid_turn_is_bridged_by_the_kit(tmp_path) -> None:
    svc = RunningService(["--mock", "4", "--mock-kit", "--mock-kit-drop", "2", "--mock-speed", SPEED],
                         f"sqlite:///{tmp_path / 'store.sqlite3'}").start(60)
    try:
        with svc.client() as c:
            for body, status, words in (({"devices": ["mock-1", "mock-1"]}, 422, "named twice"),
                                        ({"devices": ["mock-1"]}, 422, "at least 2"),
                                        ({"devices": ["mock-1", "nope"]}, 404, "no device 'nope'"),
                                        ({"devices": ["mock-1", "mock-2"], "extra": 1}, 422, "extra")):
                bad = c.post("/kits/calibrate", json=body)
                assert bad.status_code == status and words in bad.text.lower(), bad.text
            assert c.get("/devices/mock-1").json()["simulated_truth"] is not None
            started = c.post("/kits/calibrate", json={"devices": ["mock-1", "mock-2", "mock-3"]})
            assert started.status_code == 202, started.text
            kit_id = started.json()["session_id"]
            # the kit's event stream carries every state it went through (replayed from its first), the lost link included
            events = follow_events(svc.base, kit_id, {"done", "failed", "cancelled"}, timeout_s=90, last_event_id=0)
            seen = [e["state"] for e in events]
            assert all(e["kind"] == "kit" and e["session_id"] == kit_id for e in events)
            assert [e["_sse_id"] for e in events] == sorted({e["_sse_id"] for e in events})
            assert "reconnecting" in seen and {"still", "turn_x", "turn_y", "turn_z", "computing"} <= set(seen), seen
            # one set of prompts, said of the tray the clinician holds; a lost link names its wearable
            running = [e for e in events if e["state"] not in ("done", "failed", "cancelled")]
            assert all(e["prompt"] and "device" not in e["prompt"] for e in running), {e["prompt"] for e in running}
            assert any(e["prompt"].startswith("Turn the tray one full turn") for e in running)
            lost = {e["prompt"] for e in running if e["state"] == "reconnecting"}
            assert lost == {"Keep the tray still and close to the receiver: the link to mock-2 was lost. "
                            "The kit goes on when it reconnects."}, lost
            assert all(e["prompt"] is None for e in events if e["state"] == "done")
            said = {w["message"] for e in events for w in e["warnings"] if w["code"] == "link_lost"}
            assert said and all(m.startswith("mock-2: ") for m in said), said
            snap = c.get(f"/sessions/{kit_id}").json()
            assert snap["state"] == events[-1]["state"] == "done"
            resumed = follow_events(svc.base, kit_id, {"done"}, last_event_id=events[-3]["_sse_id"])
            assert [e["_sse_id"] for e in resumed] == [e["_sse_id"] for e in events[-2:]]  # Last-Event-ID resumes
            devices = {d["device_id"]: d for d in snap["devices"]}
            assert devices["mock-2"]["lost_samples"] > 0
            for name, d in devices.items():
                assert d["state"] == "done" and d["passed"], (name, d["reason"])
            bridged = [t for t in devices["mock-2"]["result"]["residuals"]["turns"] if t.get("bridged_by_kit")]
            assert len(bridged) == 1 and bridged[0]["axis"] == "x"
            k, std = np.array(devices["mock-2"]["result"]["k"]), np.array(devices["mock-2"]["result"]["uncertainty"]["k"])
            assert np.all(np.abs(k - _truth(c, "mock-2")) < 5 * std + 2e-5)
            # on SQLite too, two accepts of the kit at once store it once: one 200, one 409 naming a wearable
            both = at_once([lambda: c.post(f"/kits/{kit_id}/accept"), lambda: c.post(f"/kits/{kit_id}/accept")])
            assert sorted(r.status_code for r in both) == [200, 409], [r.text for r in both]
            refused = next(r for r in both if r.status_code == 409).json()["detail"]
            assert "mock-1" in refused and "already" in refused and "session " not in refused, refused
            accepts = [e for e in c.get("/audit", params={"limit": 50}).json() if e["action"] == "calibration.accept"]
            assert sorted(e["device_id"] for e in accepts) == sorted(devices)  # one entry a wearable, not two
            # the day's next kit, of a wearable whose clock ran on through this one and one that has not streamed: the
            # service counts each wearable's time from its first reading, so their stamps are a kit's length apart,
            # which the motion aligns. Before, that kit was refused ("mock-4 shares only 0.0 s of motion with mock-3")
            again = c.post("/kits/calibrate", json={"devices": ["mock-3", "mock-4"]})
            assert again.status_code == 202, again.text
            snap = _until_ended(c, again.json()["session_id"])
            for d in snap["devices"]:
                assert d["state"] == "done" and d["passed"], (d["device_id"], d["reason"])
                k, std = np.array(d["result"]["k"]), np.array(d["result"]["uncertainty"]["k"])
                assert np.all(np.abs(k - _truth(c, d["device_id"])) < 5 * std + 2e-5), (k - _truth(c, d["device_id"])) / std
    finally:
        svc.stop()


def test_a_turn_about_the_vertical_the_tray_stopped_short_is_asked_again_once_the_kits_calibration_points_to_it(tmp_path) -> None:
    """The clinician stops the tray's first Z turn where mock-1 reads 296 deg, flat on the table: mock-1 passes it live,
    the others read it short and the kit closes theirs with mock-1's. Every wearable's result then points to that turn:
    the tray is asked it again, once, and every wearable passes. Before, all three failed, out of tolerance."""
    svc = RunningService(["--mock", "3", "--mock-kit", "--mock-speed", SPEED, "--mock-seed", "1", "--mock-scenario", "hand:short"],
                         f"sqlite:///{tmp_path / 'store.sqlite3'}").start(60)
    try:
        with svc.client() as c:
            kit_id = c.post("/kits/calibrate", json={"devices": ["mock-1", "mock-2", "mock-3"]}).json()["session_id"]
            snap = _until_ended(c, kit_id)
            assert [(d["device_id"], d["state"], d["passed"]) for d in snap["devices"]] == \
                [("mock-1", "done", True), ("mock-2", "done", True), ("mock-3", "done", True)], snap["reason"]
            said = [(w["code"], w["message"]) for w in snap["warnings"]]
            assert said[-1] == ("kit_turn_again", "The kit's calibration points every wearable to the turn about Z: most "
                                "likely that turn was not a full turn. Once more: turn the tray one full turn about Z, "
                                "stopping when it is back against the block.")
            # the wearables whose turn the kit closed name only the one that passed it
            closed = [m for code, m in said if code == "kit_closed_turn"]
            assert sorted(m.split(":")[0] for m in closed) == ["mock-2", "mock-3"], closed
            assert all("The rest of the kit (mock-1) passed that turn" in m for m in closed), closed
            own = [c.get(f"/sessions/{d['session_id']}").json() for d in snap["devices"]]
            assert [s["attempt"] for s in own] == [2, 2, 2]
    finally:
        svc.stop()
