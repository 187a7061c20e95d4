"""Writing the accepted calibration to the wearable over real HTTP: `gyrocal serve --mock` on SQLite and on
PostgreSQL (as the service's non-owner role), writes racing each other and a session, a refused store write,
and the flag for a device that holds another calibration."""

from __future__ import annotations

import time
from collections.abc import Callable

import httpx
import pytest
from server_fixtures import API_TOKEN, RunningService, at_once, store_outage
from test_server_integrity import _live_session, _upload_session

from server.store import Store

MOCK = ["--mock", "2", "--mock-speed", "40", "--mock-seed", "5"]


def _post(svc: RunningService, path: str, json: object = None) -> Callable[[], httpx.Response]:
    def call() -> httpx.Response:
        with httpx.Client(base_url=svc.base, headers={"Authorization": f"Bearer {API_TOKEN}"}, timeout=60, verify=False) as c:
            return c.post(path, json=json)

    return call


def test_the_current_calibration_is_written_verified_and_flagged_when_superseded(service_store: tuple[str, str]) -> None:
    owner, url = service_store
    svc = RunningService(MOCK, url).start()
    try:
        with svc.client() as c:
            sid = _live_session(svc)
            dev = c.get("/devices/mock-1").json()
            assert dev["write_back"] and dev["held_state"] == "none"  # read from the device when the session connected
            first = c.post(f"/sessions/{sid}/accept").json()["calibration"]
            assert c.get("/devices/mock-1").json()["held_state"] == "none"

            # two clinicians press "write to device" at once, and a third starts a session on it
            answers = at_once([_post(svc, "/devices/mock-1/calibration/write")] * 2 + [_post(svc, "/devices/mock-1/calibrate", {})])
            for r in answers[:2]:
                assert r.status_code in (200, 409), r.text
                if r.status_code == 409:
                    assert "being written" in r.json()["detail"] or "in a calibration session" in r.json()["detail"]
            assert answers[2].status_code in (202, 409), answers[2].text
            if answers[2].status_code == 202:
                assert c.post(f"/sessions/{answers[2].json()['session_id']}/cancel").status_code == 200
            else:
                assert "being written" in answers[2].json()["detail"]
            ok = next((r.json() for r in answers[:2] if r.status_code == 200), None)
            if ok is None:  # the session won the race: the write works once it has ended
                ok = c.post("/devices/mock-1/calibration/write").json()
            assert ok["verified"] and ok["calibration_id"] == first["id"] and ok["held_state"] == "current"
            assert ok["warnings"] == []  # the same sensor, power-up and temperature as it was calibrated at
            k = [ok["held"]["K"][i][i] for i in range(3)]
            assert k == pytest.approx(first["k"], rel=1e-6) and ok["held"]["b"] == pytest.approx(first["b"], abs=1e-6)
            dev = c.get("/devices/mock-1").json()
            assert (dev["held_state"], dev["held_calibration_id"]) == ("current", first["id"])

            # a new calibration is accepted: the device still holds the first one, and the page is told so
            second = c.post(f"/sessions/{_live_session(svc)}/accept").json()["calibration"]
            dev = c.get("/devices/mock-1").json()
            assert (dev["held_state"], dev["held_calibration_id"]) == ("other", first["id"])
            r = c.post("/devices/mock-1/calibration/write", json={"calibration_id": second["id"]})
            assert r.status_code == 200 and r.json()["held_state"] == "current", r.text

            # what cannot be written says why, and changes nothing
            for body, code, words in (({"calibration_id": first["id"] + 1000}, 404, "not one of"),
                                      ({"calibration_id": "one"}, 422, ""), ({"K": [1, 1, 1]}, 422, "")):
                r = c.post("/devices/mock-1/calibration/write", json=body)
                assert r.status_code == code and words in r.text, r.text
            r = c.post("/devices/mock-2/calibration/write")
            assert r.status_code == 409 and "no accepted calibration" in r.json()["detail"]
            upload = c.post(f"/sessions/{_upload_session(svc, 3)}/accept").json()["calibration"]
            r = c.post("/devices/mock-1/calibration/write", json={"calibration_id": upload["id"]})
            assert r.status_code == 404 and "not one of" in r.json()["detail"]
            r = c.post("/devices/upload-1/calibration/write")
            assert r.status_code == 409 and "not reachable" in r.json()["detail"]

            # the store refuses to record it: 503, the device holds it, a second write records it
            store_outage(owner, True, [("devices", "UPDATE", None)])
            try:
                r = c.post("/devices/mock-1/calibration/write", json={"calibration_id": first["id"]})
                assert r.status_code == 503 and "holds calibration" in r.json()["detail"], r.text
            finally:
                store_outage(owner, False, [("devices", "UPDATE", None)])
            assert c.get("/devices/mock-1").json()["held_calibration_id"] == second["id"]
            r = c.post("/devices/mock-1/calibration/write", json={"calibration_id": first["id"]})
            assert r.status_code == 200 and r.json()["held_state"] == "other"
            assert c.get("/devices/mock-1").json()["held_state"] == "other"

            # a calibration of another sensor (imported for this device id, with another serial) is never written to it
            foreign = c.post("/devices/mock-1/calibrations", params={"serial": "NOT-THIS-ONE"},
                             content='{"k": [1.01, 1, 1], "b": [0, 0, 0]}', headers={"Content-Type": "application/json"})
            assert foreign.status_code == 201, foreign.text
            r = c.post("/devices/mock-1/calibration/write", json={"calibration_id": foreign.json()["calibration"]["id"]})
            assert r.status_code == 409 and "another sensor" in r.json()["detail"] and "NOT-THIS-ONE" in r.json()["detail"], r.text
            assert c.get("/devices/mock-1").json()["held_calibration_id"] == first["id"]
        store = Store(owner)
        writes = [e for e in store.audit_log("mock-1") if e["action"] == "device.write_back"]
        assert [e["detail"]["calibration_id"] for e in writes][:2] == [first["id"], second["id"]]
        assert store.verify().ok
    finally:
        svc.stop()


def test_a_device_that_cannot_hold_one_says_so(tmp_path) -> None:
    svc = RunningService(["--mock", "1", "--mock-model", "thingy52", "--mock-speed", "1"],
                         f"sqlite:///{tmp_path / 'store.sqlite3'}").start()
    try:
        with svc.client() as c:
            dev = c.get("/devices/mock-1").json()
            assert not dev["write_back"] and any("cannot hold a calibration" in t for t in dev["limitations"])
            cal = c.post(f"/sessions/{_upload_session(svc, 4, 'mock-1')}/accept").json()["calibration"]
            r = c.post("/devices/mock-1/calibration/write")
            assert r.status_code == 409 and "cannot hold a calibration" in r.json()["detail"], r.text
            assert c.get("/devices/mock-1").json()["current_calibration"]["id"] == cal["id"]
    finally:
        svc.stop()


def test_imports_and_a_verification_racing_a_session_on_one_device(service_store: tuple[str, str]) -> None:
    """The same calibration file imported twice at once becomes one calibration; a verification turn and a guided
    session started at once on one device: one starts, the other is told the device is busy."""
    _, url = service_store
    svc = RunningService(MOCK, url).start()
    try:
        body = '{"k": [1.01, 0.99, 1.0], "b": [0.1, 0.0, -0.1]}'

        def imported() -> httpx.Response:
            with httpx.Client(base_url=svc.base, headers={"Authorization": f"Bearer {API_TOKEN}"}, timeout=60, verify=False) as c:
                return c.post("/devices/mock-1/calibrations", content=body, headers={"Content-Type": "application/json"})

        answers = at_once([imported] * 4)
        assert sorted(r.status_code for r in answers) == [201, 409, 409, 409], [r.text for r in answers]
        cal = next(r.json()["calibration"] for r in answers if r.status_code == 201)
        assert all("already, as calibration #" + str(cal["id"]) in r.json()["detail"] for r in answers if r.status_code == 409)

        verify, session = at_once([_post(svc, f"/calibrations/{cal['id']}/verify", {}), _post(svc, "/devices/mock-1/calibrate", {})])
        assert sorted((verify.status_code, session.status_code)) == [202, 409], (verify.text, session.text)
        with svc.client() as c:
            if session.status_code == 202:
                assert "busy" not in session.text
                assert c.post(f"/sessions/{session.json()['session_id']}/cancel").status_code == 200
            else:
                assert "mock-1" in session.json()["detail"]
                for _ in range(600):
                    if c.get(verify.headers["location"]).json()["state"] in ("done", "failed"):
                        break
                    time.sleep(0.1)
            assert len(c.get("/devices/mock-1/calibrations").json()) == 1
        assert Store(url).verify().ok
    finally:
        svc.stop()
