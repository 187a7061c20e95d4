"""The service's history under races, outages, crashes and tampering: a real `gyrocal serve`, real HTTP,
real SQLite and PostgreSQL (the service connecting as its non-owner role)."""

from __future__ import annotations

import io
import os
import signal
import time
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest
from server_fixtures import API_TOKEN, RunningService, at_once, follow_events, store_outage
from sqlalchemy import create_engine, text

from calib.io.readers import write_native_csv
from calib.simulator import simulate
from server.store import Store

END = {"done", "failed", "cancelled"}
MOCK = ["--mock", "1", "--mock-speed", "40", "--mock-seed", "5"]


def _recording_csv(seed: int) -> bytes:
    rec, _ = simulate(seed, noise=0.03)
    buf = io.StringIO()
    write_native_csv(rec, buf)
    return buf.getvalue().encode()


def _live_session(svc: RunningService, device: str = "mock-1") -> str:
    with svc.client() as c:
        r = c.post(f"/devices/{device}/calibrate", json={})
        assert r.status_code == 202, r.text
        sid = r.json()["session_id"]
    events = follow_events(svc.base, sid, END, timeout_s=90, last_event_id=0)
    assert events[-1]["state"] == "done", events[-1]
    return sid


def _upload_session(svc: RunningService, seed: int, device: str = "upload-1") -> str:
    with svc.client() as c:
        r = c.post(f"/devices/{device}/calibrate", content=_recording_csv(seed),
                   params={"sensor_model": "ICM-20948", "firmware": "1.0"}, headers={"Content-Type": "text/csv"})
        assert r.status_code == 200 and r.json()["passed"], r.text
        return r.json()["session_id"]


def _at_once(svc: RunningService, sid: str, actions: list[str]) -> list[httpx.Response]:
    """POST the decisions at the same moment from as many threads (each its own connection)."""

    def post(action: str) -> Callable[[], httpx.Response]:
        def call() -> httpx.Response:
            with httpx.Client(base_url=svc.base, headers={"Authorization": f"Bearer {API_TOKEN}"}, timeout=60, verify=False) as c:
                return c.post(f"/sessions/{sid}/{action}")

        return call

    return at_once([post(a) for a in actions])


def test_concurrent_decisions_over_http_store_one_outcome(service_store: tuple[str, str]) -> None:
    owner, url = service_store
    svc = RunningService(MOCK, url).start()
    tried = stored = 0
    try:
        rounds = [("live", ["accept"] * 4), ("live", ["accept", "discard", "accept", "discard"])]
        rounds += [("upload", ["accept"] * 4)] * 3 + [("upload", ["discard", "accept", "accept", "discard"])] * 3
        for i, (kind, actions) in enumerate(rounds):
            sid = _live_session(svc) if kind == "live" else _upload_session(svc, 20 + i)
            answers = _at_once(svc, sid, actions)
            tried += sum(a == "accept" for a in actions)
            codes = [r.status_code for r in answers]
            assert sorted(codes) == [200] + [409] * (len(actions) - 1), [r.text for r in answers]
            winner = actions[codes.index(200)]
            for r in answers:
                if r.status_code == 409:
                    assert "already by" in r.json()["detail"], r.text
            with svc.client() as c:
                row = c.get(f"/sessions/{sid}").json()
                assert row["decision"] == ("accepted" if winner == "accept" else "discarded")
            stored += winner == "accept"
        store = Store(owner)
        assert store.calibration_count() == stored
        for dev in ("mock-1", "upload-1"):
            cals = store.calibrations(dev)
            assert len({c.session_id for c in cals}) == len(cals)
            current = store.current_calibration(dev)
            if current is not None:
                assert store.session(current.session_id)["decision"] == "accepted"
        assert store.verify().ok
        with svc.client() as c:
            health = c.get("/health", params={"verify": "true"}).json()
            assert health["status"] == "ok" and health["integrity"]["rows"]["calibrations"] == stored
    finally:
        svc.stop()
    print(f"concurrent accepts tried: {tried}, calibration rows stored: {stored}")


# the writes that end a session: its row's end, and its recording
SESSION_END = [("sessions", "UPDATE OF ended_at", "NEW.ended_at IS NOT NULL"), ("recordings", "INSERT", None)]


def test_a_store_outage_at_a_sessions_end_is_repaired_by_the_accept(service_store: tuple[str, str]) -> None:
    owner, url = service_store
    svc = RunningService(MOCK, url).start()
    try:
        store_outage(owner, True, SESSION_END)
        try:
            with svc.client() as c:
                sid = c.post("/devices/mock-1/calibrate", json={}).json()["session_id"]
            events = follow_events(svc.base, sid, END, timeout_s=90, last_event_id=0)
            live_end = events[-1]
            assert live_end["state"] == "done"
            time.sleep(0.5)
            store = Store(owner)
            assert store.session(sid)["ended_at"] is None  # the end was not written
        finally:
            store_outage(owner, False, SESSION_END)
        with svc.client() as c:
            r = c.post(f"/sessions/{sid}/accept")
            assert r.status_code == 200, r.text
        row = store.session(sid)
        assert row["state"] == "done" and row["passed"] is True
        assert row["ended_at"] == live_end["ended_at"] and row["decided_at"] >= row["ended_at"]
        info = row["info"]
        assert info["checks"] == live_end["checks"] and info["turns"] == live_end["turns"]
        assert info["warnings"] == live_end["warnings"] and "lost_samples" in info and info["samples"] > 1000
        actions = [e["action"] for e in store.audit_log() if e["session_id"] == sid]
        assert actions.count("session.done") == 1 and "calibration.accept" in actions
        assert store.recording(sid) is not None and store.verify().ok
    finally:
        svc.stop()


def test_kill_9_mid_turn_leaves_the_recording_for_the_audit(service_store: tuple[str, str]) -> None:
    owner, url = service_store
    svc = RunningService(["--mock", "1", "--mock-speed", "1", "--mock-seed", "5"], url).start()
    try:
        with svc.client() as c:
            sid = c.post("/devices/mock-1/calibrate", json={}).json()["session_id"]
        follow_events(svc.base, sid, {"turn_x"}, timeout_s=60, last_event_id=0)
        time.sleep(2.5)  # into the turn; the spool writes once a second
        assert svc.proc is not None
        os.kill(svc.proc.pid, signal.SIGKILL)
        svc.proc.wait(10)
    finally:
        svc.stop()
    recordings_before = Store(owner).verify().rows["recordings"]
    again = RunningService(MOCK, url).start()
    try:
        with again.client() as c:
            # the first word on the history, asked at once, counts the recording the restart recovered
            assert c.get("/health", params={"verify": "true"}).json()["integrity"]["rows"]["recordings"] == recordings_before + 1
            row = c.get(f"/sessions/{sid}").json()
            assert row["state"] == "failed" and row["reason_code"] == "service_restarted"
            r = c.get(f"/sessions/{sid}/recording")
            assert r.status_code == 200, r.text
        from calib.io.readers import parse_recording_text

        rec = parse_recording_text(r.content, None, "native", "recovered")
        assert len(rec) > 104 * 4 and rec.t[-1] - rec.t[0] > 4.0  # the initial rest and part of the turn
        assert float(abs(rec.gyro).max()) > 20.0  # the turn had begun
        assert Store(owner).verify().ok
    finally:
        again.stop()


def test_health_reports_the_first_broken_link(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'store.sqlite3'}"
    svc = RunningService([], url).start()
    try:
        with svc.client() as c:
            assert c.get("/health").json()["integrity"]["ok"] is True
            sid = _upload_session(svc, 3)
            assert c.post(f"/sessions/{sid}/accept").status_code == 200
            eng = create_engine(url)
            with eng.begin() as conn:  # someone with the file edits the stored calibration
                conn.execute(text("DROP TRIGGER calibrations_no_update"))
                conn.execute(text("UPDATE calibrations SET k_x = k_x * 1.1"))
            eng.dispose()
            time.sleep(2.1)
            health = c.get("/health", params={"verify": "true"}).json()
            assert health["status"] == "tampered"
            link = health["integrity"]["first_broken_link"]
            assert link["chain"] == "calibrations" and link["seq"] == 1 and "does not match" in link["problem"]
    finally:
        svc.stop()


@pytest.mark.parametrize("sensor", [{}, {"sensor_model": "LSM9DS1"}])
def test_an_upload_is_accepted_only_with_its_sensor_and_says_it_came_from_an_upload(tmp_path: Path, sensor: dict[str, str]) -> None:
    svc = RunningService([], f"sqlite:///{tmp_path / 'store.sqlite3'}").start()
    try:
        with svc.client() as c:
            r = c.post("/devices/wrist-9/calibrate", content=_recording_csv(4), headers={"Content-Type": "text/csv"})
            sid = r.json()["session_id"]
            r = c.post(f"/sessions/{sid}/accept", json=sensor)
            if not sensor:
                assert r.status_code == 409 and "sensor_model" in r.json()["detail"]
                assert c.get("/devices/wrist-9/calibration").status_code == 404
                r = c.post(f"/sessions/{sid}/accept", json={"sensor_model": "ICM-20948", "firmware": "2.0.1"})
            assert r.status_code == 200, r.text
            cal = r.json()["calibration"]
            assert cal["source"] == "upload" and cal["sensor_model"] == (sensor.get("sensor_model") or "ICM-20948")
            assert c.get("/devices/wrist-9/calibrations").json()[0]["source"] == "upload"
    finally:
        svc.stop()
