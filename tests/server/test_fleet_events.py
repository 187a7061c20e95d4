"""Live events across the gateways of a fleet (PostgreSQL LISTEN/NOTIFY): a session run on one gateway is followed,
live, from another gateway's event stream and accepted there; fleet pages everywhere hear of it; the database
restarting under running sessions loses nothing; gateways meet an older schema (one upgrades it) and a newer one
(refused with what to do)."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from server_fixtures import (
    PostgresServer,
    RunningService,
    at_once,
    follow_events,
    make_v1_store,
    running_postgres,
    wait_for,
)
from sqlalchemy import create_engine, text

from server.store.schema import head_revision

END = {"done", "failed", "cancelled"}
RUNNING = {"still", "turn_x", "turn_y", "turn_z", "computing"}


def _gateway(name: str, first: int, n: int, url: str, speed: str = "10", *extra: str) -> RunningService:
    return RunningService(["--gateway", name, "--mock", str(n), "--mock-first", str(first), "--mock-speed", speed,
                           "--lease-s", "20", *extra], url)


def _post(svc: RunningService, path: str) -> httpx.Response:
    with svc.client(timeout_s=60) as c:
        return c.post(path, json={})


class FleetStream:
    """A fleet page's event stream (GET /fleet/events), read in the background."""

    def __init__(self, base: str) -> None:
        self.views: list[dict[str, Any]] = []
        self.error: Exception | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, args=(base,), daemon=True)
        self._thread.start()
        wait_for(lambda: self.views, 30, "the fleet stream's first view")

    def _read(self, base: str) -> None:
        try:
            with httpx.stream("GET", f"{base}/fleet/events", timeout=httpx.Timeout(120), verify=False) as r:
                assert r.status_code == 200
                for line in r.iter_lines():
                    if self._stop.is_set():
                        return
                    if line.startswith("data:"):
                        self.views.append(json.loads(line[5:]))
        except httpx.HTTPError as exc:
            if not self._stop.is_set():  # the stream broke while the test still read it
                self.error = exc

    def device(self, device_id: str) -> Iterator[dict[str, Any]]:
        """The device's row in every view received so far."""
        for view in list(self.views):
            yield from (d for d in view["devices"] if d["id"] == device_id)

    def close(self) -> None:
        """Stop reading; the stream must not have broken before."""
        self._stop.set()
        assert self.error is None, f"the fleet's event stream broke: {self.error}"


@pytest.fixture
def fleet_db(postgres) -> str:  # noqa: F811
    return postgres.service_url(postgres.create_database())


def test_a_session_is_followed_live_and_accepted_from_another_gateway(fleet_db: str) -> None:
    a, b = at_once([lambda: _gateway("room-a", 1, 1, fleet_db).start(60), lambda: _gateway("room-b", 2, 1, fleet_db).start(60)])
    try:
        fleet_b = FleetStream(b.base)
        r = _post(a, "/devices/mock-1/calibrate")
        assert r.status_code == 202, r.text
        sid = r.json()["session_id"]
        # room-b's stream of a session room-a runs: room-b has no such session in memory, only the store's row, so
        # every running state it shows came through the database's notifications
        events = follow_events(b.base, sid, END, timeout_s=120, last_event_id=0)
        assert all(e["remote"] == {"gateway": "room-a", "url": a.base} for e in events), events[0]
        states = [e["state"] for e in events]
        assert RUNNING & set(states[1:-1]), states
        assert any(e.get("live") for e in events), "no live angle relayed"
        end = events[-1]
        assert end["state"] == "done" and end["passed"] and end["result"]["k"], end  # a result compresses to travel
        with b.client() as c:  # GET answers with the relayed state too
            assert c.get(f"/sessions/{sid}").json()["state"] == "done"

        # accepted on room-b: the store decides; room-a's own stream (and page) shows the decision
        accepted = _post(b, f"/sessions/{sid}/accept")
        assert accepted.status_code == 200, accepted.text
        decided = follow_events(a.base, sid, END, timeout_s=30, last_event_id=0)
        assert wait_for(lambda: (s := _get(a, f"/sessions/{sid}")) and s.get("decision") == "accepted" and s, 15,
                     "room-a told of the decision"), decided
        assert _post(a, f"/sessions/{sid}/accept").status_code == 409  # decided once, wherever

        # room-b's fleet page heard each step without asking: in a session on room-a, then calibrated
        wait_for(lambda: any(d["calibration"]["status"] == "current" for d in fleet_b.device("mock-1")), 15, "fleet current")
        rows = list(fleet_b.device("mock-1"))
        busy = [d for d in rows if d["in_session"]]
        assert busy and all(d["gateway"] == "room-a" and d["session"] == sid for d in busy), busy
        assert all(d["activity"] == "calibration" for d in busy), [d["activity"] for d in busy]
        assert rows[-1]["calibration"]["status"] == "current" and not rows[-1]["in_session"]
        fleet_b.close()
    finally:
        a.stop()
        b.stop()


def _get(svc: RunningService, path: str) -> dict[str, Any]:
    with svc.client() as c:
        r = c.get(path)
        assert r.status_code == 200, r.text
        return dict(r.json())


@pytest.fixture
def own_postgres() -> Iterator[PostgresServer]:
    """A PostgreSQL of this test's own, to restart."""
    with running_postgres() as server:
        yield server


def test_the_database_restarting_under_running_sessions_loses_nothing(own_postgres: PostgresServer) -> None:
    db = own_postgres.service_url(own_postgres.create_database())
    a, b = at_once([lambda: _gateway("room-a", 1, 3, db, "4").start(60), lambda: _gateway("room-b", 4, 2, db, "4").start(60)])
    try:
        fleet_b = FleetStream(b.base)
        started = {dev: (gw, _post(gw, f"/devices/{dev}/calibrate")) for dev, gw in
                   (("mock-1", a), ("mock-2", a), ("mock-3", a), ("mock-4", b), ("mock-5", b))}
        assert all(r.status_code == 202 for _, r in started.values()), [r.text for _, r in started.values()]
        sids = {dev: (gw, r.json()["session_id"]) for dev, (gw, r) in started.items()}
        follow_events(a.base, sids["mock-1"][1], {"turn_x"}, timeout_s=60, last_event_id=0)

        followed: dict[str, Any] = {}
        remote = threading.Thread(target=lambda: followed.update(
            events=follow_events(b.base, sids["mock-1"][1], END, timeout_s=180, last_event_id=0)), daemon=True)
        remote.start()
        wait_for(lambda: "remote" in _get(b, f"/sessions/{sids['mock-1'][1]}"), 30, "room-b following the session")
        own_postgres.restart(down_s=2.0)  # every connection of both gateways cut mid-session

        ends = at_once([lambda gw=gw, sid=sid: follow_events(gw.base, sid, END, timeout_s=180, last_event_id=0)[-1]
                        for gw, sid in sids.values()], timeout_s=200)
        unfinished = [(dev, e["state"], e.get("reason"), e.get("message")) for dev, e in zip(sids, ends, strict=True)
                      if e["state"] != "done"]
        assert not unfinished, unfinished
        remote.join(60)
        assert followed["events"][-1]["state"] == "done", followed["events"][-1]  # room-b's follower caught up
        accepted = at_once([lambda gw=gw, sid=sid: _post(gw, f"/sessions/{sid}/accept") for gw, sid in sids.values()])
        assert all(r.status_code == 200 for r in accepted), [r.text for r in accepted]

        for gw in (a, b):  # every calibration and recording, from every gateway; the history intact
            with gw.client() as c:
                for _gw, sid in sids.values():
                    rec = c.get(f"/sessions/{sid}/recording")
                    assert rec.status_code == 200 and rec.headers["X-Recording-SHA256"], sid
                for dev in sids:
                    assert c.get(f"/devices/{dev}/calibration").status_code == 200
                assert c.get("/health", params={"verify": "true"}).json()["integrity"]["ok"]
        wait_for(lambda: all(d["calibration"]["status"] == "current" for d in fleet_b.views[-1]["devices"]), 20,
              "the fleet page on room-b showing every calibration")
        fleet_b.close()
    finally:
        a.stop()
        b.stop()


def test_gateways_meet_an_older_schema_and_a_newer_one(postgres) -> None:  # noqa: F811
    """Three gateways start at once on a store gyrocal 0.1 left (schema version 1): one upgrades it, all run, the old
    history is kept. A gateway meeting a store a newer gyrocal upgraded refuses to start, says what to do, and
    changes nothing."""
    owner = postgres.create_database()
    make_v1_store(owner)
    gws = at_once([lambda n=n: _gateway(f"room-{n}", n, 1, owner, "10", "--allow-db-owner").start(60) for n in (1, 2, 3)])
    try:
        view = _get(gws[0], "/fleet")
        assert sorted(g["name"] for g in view["gateways"]) == ["room-1", "room-2", "room-3"]
        assert _get(gws[2], "/devices/dev-1/calibration")["k"][0] == pytest.approx(1.01)  # 0.1's calibration, kept
        integrity = _get(gws[1], "/health?verify=true")["integrity"]  # the old history chained once, not three times
        assert integrity["ok"] and integrity["rows"]["calibrations"] == 2 and integrity["rows"]["audit_log"] >= 5, integrity
        eng = create_engine(owner.replace("postgresql://", "postgresql+psycopg://"))
        with eng.begin() as conn:
            assert conn.execute(text("SELECT version_num FROM alembic_version")).scalar_one() == head_revision()  # upgraded to the newest
            conn.execute(text("UPDATE alembic_version SET version_num = '0099'"))  # a newer gyrocal was here
        newer = _gateway("room-4", 4, 1, owner, "10", "--allow-db-owner")
        with pytest.raises(RuntimeError) as refused:
            newer.start(60)
        said = str(refused.value)
        assert "newer than this gyrocal" in said and "upgrade gyrocal" in said and "Traceback" not in said, said
        with eng.begin() as conn:
            assert conn.execute(text("SELECT version_num FROM alembic_version")).scalar_one() == "0099"
            assert conn.execute(text("SELECT COUNT(*) FROM gateways WHERE name = 'room-4'")).scalar_one() == 0
        eng.dispose()
    finally:
        for gw in gws:
            gw.stop()
