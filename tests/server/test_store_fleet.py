"""The fleet's store (gateways, sightings, leases) on SQLite and PostgreSQL: many gateways asking at once for one
wearable get one lease; a dead gateway's lease expires, and its open session is ended once, with its samples."""

from __future__ import annotations

import time

from server_fixtures import at_once

from server.store import SessionEnd, Store


def test_gateways_register_heartbeat_and_report_what_they_see(store_url: str) -> None:
    store = Store(store_url)
    store.register_gateway("room-1", "http://gw1:8000", "1.0")
    store.register_gateway("room-2", None, "1.0")
    store.heartbeat("room-1", 30.0, {"aa": -60, "bb": None}, {})
    store.heartbeat("room-2", 30.0, {"bb": -75}, {})
    assert [g["name"] for g in store.gateways()] == ["room-1", "room-2"]
    seen = {(s["device_id"], s["gateway"]): s["rssi_dbm"] for s in store.sightings()}
    assert seen == {("aa", "room-1"): -60, ("bb", "room-1"): None, ("bb", "room-2"): -75}
    store.register_gateway("room-1", "http://gw1:9000", "1.1")  # restarted: same row, new URL and version
    assert store.gateways()[0]["url"] == "http://gw1:9000" and len(store.gateways()) == 2


def test_six_gateways_asking_at_once_for_one_wearable_get_one_lease(store_url: str) -> None:
    stores = [Store(store_url) for _ in range(6)]
    leases = at_once([lambda i=i: stores[i].take_lease("dev-1", f"room-{i}", f"s{i}", 30.0) for i in range(6)])
    winners = {lease.gateway for lease in leases}
    assert len(winners) == 1, leases  # everyone is told the same holder
    winner = winners.pop()
    assert [lease.gateway == f"room-{i}" for i, lease in enumerate(leases)].count(True) == 1
    assert stores[0].leases()[0].gateway == winner
    again = stores[0].take_lease("dev-1", winner, "s-next", 30.0)  # the holder may renew it for its next session
    assert again.gateway == winner and again.holder == "s-next"
    other = next(f"room-{i}" for i in range(6) if f"room-{i}" != winner)
    assert stores[0].take_lease("dev-1", other, "x", 30.0).gateway == winner
    stores[0].release_lease("dev-1", other, "x")  # not its lease: nothing happens
    assert stores[0].leases()[0].gateway == winner
    stores[0].release_lease("dev-1", winner, "s-next")
    assert stores[0].leases() == [] and stores[0].take_lease("dev-1", other, "y", 30.0).gateway == other
    for st in stores:
        st.close()


def test_a_dead_gateways_lease_expires_and_its_session_is_ended_once(store_url: str) -> None:
    store = Store(store_url)
    store.register_gateway("room-1", None, "1.0")
    store.create_session("s" * 32, "dev-1", "live", "turn_x", "closure", "alice", "1.0", gateway="room-1")
    store.spool_samples("s" * 32, 0, "t,gx,gy,gz", b"0.0,0.1,0.2,0.3\n0.01,0.1,0.2,0.3\n", 2)
    store.create_session("t" * 32, "dev-2", "live", "still", "closure", "alice", "1.0", gateway="room-2")
    assert store.take_lease("dev-1", "room-1", "s" * 32, 0.3).gateway == "room-1"
    assert store.take_lease("dev-2", "room-2", "t" * 32, 60.0).gateway == "room-2"
    assert store.take_lease("dev-1", "room-2", "u", 30.0).gateway == "room-1"  # not expired yet
    assert store.heartbeat("room-2", 60.0, {}, {"dev-2": "t" * 32, "dev-9": "gone"}) == 1  # room-2 renews what it runs
    time.sleep(0.5)
    swept = at_once([lambda: Store(store_url).sweep_expired_leases() for _ in range(3)])
    assert sorted(len(s) for s in swept) == [0, 0, 1], swept  # one sweeper drops it, the others find nothing
    row = store.session("s" * 32)
    assert row is not None and row["state"] == "failed" and row["reason_code"] == "gateway_lost"
    assert "room-1" in row["reason"] and row["info"]["samples"] == 2
    assert store.session("t" * 32)["ended_at"] is None  # room-2's session goes on
    assert [lease.device_id for lease in store.leases()] == ["dev-2"]
    assert store.take_lease("dev-1", "room-2", "u", 30.0).gateway == "room-2"  # the device is free for another gateway
    assert sum(1 for e in store.audit_log() if e["action"] == "session.failed") == 1
    assert store.verify().ok


def test_a_gateway_restarting_fails_only_its_own_open_sessions(store_url: str) -> None:
    store = Store(store_url)
    for sid, gw in (("a" * 32, "room-1"), ("b" * 32, "room-2"), ("c" * 32, None)):
        store.create_session(sid, "dev-" + sid[0], "live", "still", "closure", "alice", "1.0", gateway=gw)
    assert store.fail_unfinished_sessions("restarted", gateway="room-1") == 1
    assert [store.session(s * 32)["state"] for s in "abc"] == ["failed", "still", "still"]
    assert store.fail_unfinished_sessions("restarted") == 1  # a service on its own: the sessions without a gateway
    assert store.session("c" * 32)["state"] == "failed" and store.session("b" * 32)["ended_at"] is None
    store.finish_session("b" * 32, SessionEnd("cancelled"))


def test_gateways_meeting_a_new_wearable_at_once_record_it_once(store_url: str) -> None:
    """Gateways starting together that see the same new wearables each record them (and what each wearable reports
    holding) without one of them failing on the other's insert; one row per wearable."""
    stores = [Store(store_url) for _ in range(6)]
    try:
        for n in range(5):
            at_once([lambda st=st, n=n: st.upsert_device(f"shared-{n}", name=f"shared-{n}", transport="inprocess")
                     for st in stores])
            at_once([lambda st=st, n=n: st.record_held(f"held-{n}", None) for st in stores])
        ids = [d["id"] for d in stores[0].devices()]
        assert ids == sorted([*(f"held-{n}" for n in range(5)), *(f"shared-{n}" for n in range(5))])
        assert stores[0].device("shared-3")["name"] == "shared-3"
    finally:
        for st in stores:
            st.close()
