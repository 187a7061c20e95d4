"""What travels between gateways: a session's snapshot fits PostgreSQL's 8000-byte NOTIFY payload as it is, compressed,
or (too large even so) as a pointer to the store; a service on SQLite delivers fleet changes within its process."""

from __future__ import annotations

import asyncio
import json
import os

from server.fleet_events import PAYLOAD_MAX, FleetEvents, conninfo, relayed_snapshot, session_payload
from server.live.events import Event, dumps


def _event(snapshot: dict[str, object]) -> Event:
    return Event(7, "state", dumps(snapshot))


def test_a_small_snapshot_travels_as_it_is() -> None:
    snap = {"session_id": "s" * 32, "state": "turn_x", "live": {"angle_deg": [1.5, 0.0, -2.0]}}
    payload = session_payload("gw", "s" * 32, _event(snap))
    msg = json.loads(payload)
    assert "d" in msg and relayed_snapshot(msg) == snap and msg["n"] == "state"


def test_a_snapshot_with_a_result_travels_compressed_and_comes_back_whole() -> None:
    checks = [{"name": f"check {i}", "axis": "xyz"[i % 3], "value": i * 0.001, "text": "within the tolerance " * 3}
              for i in range(200)]
    snap = {"session_id": "s" * 32, "state": "done", "checks": checks}
    assert len(dumps(snap)) > PAYLOAD_MAX
    payload = session_payload("gw", "s" * 32, _event(snap))
    msg = json.loads(payload)
    assert len(payload.encode()) <= PAYLOAD_MAX and "z" in msg and "d" not in msg
    assert relayed_snapshot(msg) == snap


def test_a_snapshot_too_large_even_compressed_is_read_from_the_store() -> None:
    snap = {"session_id": "s" * 32, "state": "done", "noise": os.urandom(12_000).hex()}  # does not compress
    payload = session_payload("gw", "s" * 32, _event(snap))
    msg = json.loads(payload)
    assert len(payload.encode()) <= PAYLOAD_MAX and relayed_snapshot(msg) is None and msg["s"] == "s" * 32


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
