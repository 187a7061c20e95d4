"""What travels between gateways: a session's snapshot fits PostgreSQL's 8000-byte NOTIFY payload as it is, compressed,
or (too large even so) as a pointer to the store; a service on SQLite delivers fleet changes within its process."""

from __future__ import annotations

import asyncio
import json
import os

from server.fleet_events import PAYLOAD_MAX, FleetEvents, conninfo, relayed_snapshot, session_payload
from server.live.events import Event, dumps
from server.live.snapshot_schema import SessionOut


def _event(snapshot: SessionOut) -> Event:
    return Event(7, "state", dumps(snapshot.model_dump(mode="json", exclude_unset=True)))


def _snapshot(**fields: object) -> SessionOut:
    return SessionOut.model_validate({"session_id": "s" * 32, "device_id": "mock-1", **fields})


def test_a_small_snapshot_travels_as_it_is() -> None:
    snap = _snapshot(state="turn_x", live={"moving": True, "still_s": 0.0, "angle_deg": [1.5, 0.0, -2.0],
                                           "angle_calibrated": False, "t_device_s": 3.25})
    payload = session_payload("gw", "s" * 32, _event(snap))
    msg = json.loads(payload)
    assert "d" in msg and relayed_snapshot(msg) == snap and msg["n"] == "state"


def test_a_snapshot_with_a_result_travels_compressed_and_comes_back_whole() -> None:
    checks = [{"name": "k", "axis": "xyz"[i % 3], "value": i * 0.001, "limit": 0.2, "ok": True, "used": 0.1, "near_limit": False,
               "text": f"check {i} within the tolerance " * 3} for i in range(200)]
    snap = _snapshot(state="done", checks=checks)
    assert len(_event(snap).data) > PAYLOAD_MAX
    payload = session_payload("gw", "s" * 32, _event(snap))
    msg = json.loads(payload)
    assert len(payload.encode()) <= PAYLOAD_MAX and "z" in msg and "d" not in msg
    assert relayed_snapshot(msg) == snap


def test_a_snapshot_too_large_even_compressed_is_read_from_the_store() -> None:
    snap = _snapshot(state="done", reason=os.urandom(12_000).hex())  # does not compress
    payload = session_payload("gw", "s" * 32, _event(snap))
    msg = json.loads(payload)
    assert len(payload.encode()) <= PAYLOAD_MAX and relayed_snapshot(msg) is None and msg["s"] == "s" * 32


def test_a_snapshot_this_gateway_cannot_read_is_read_from_the_store() -> None:
    msg = {"o": "gw", "s": "s" * 32, "n": "state", "d": dumps({"session_id": "s" * 32, "state": "no such state"})}
    assert relayed_snapshot(msg) is None


def test_only_postgresql_stores_share_events() -> None:
    assert conninfo("sqlite:///x.sqlite3") is None
    assert conninfo("postgresql://u:p%40ss@db.example:5433/gy?sslmode=verify-full") == \
        "postgresql://u:p%40ss@db.example:5433/gy?sslmode=verify-full"


def test_on_sqlite_fleet_changes_reach_this_services_pages_at_once_then_throttled() -> None:
    async def run() -> list[str]:
        events = FleetEvents("sqlite:///:memory:", lambda _sid: None, lambda _sid, _snap: None)
        assert not events.shared
        await events.start()
        got: list[str] = []

        async def page() -> None:
            async for what in events.fleet_changes(quiet_s=0.5, debounce_s=0.05):
                got.append(what)
                if len(got) == 3:
                    return

        reader = asyncio.get_running_loop().create_task(page())
        await asyncio.sleep(0.01)
        events.fleet_changed("claim", "dev-1")  # the first change at once
        await asyncio.sleep(0.01)
        events.fleet_changed("release", "dev-1")  # then at most one refresh a debounce interval: the last change
        events.fleet_changed("lease", "dev-2")
        await asyncio.wait_for(reader, 5)
        await events.stop()
        return got

    assert asyncio.run(run()) == ["claim", "lease", "quiet"]  # quiet: nothing changed for quiet_s
