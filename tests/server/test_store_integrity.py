"""The store under concurrency and attack, on SQLite and a real PostgreSQL server: atomic decisions,
history that cannot be rewritten, tampering that shows, a session's end and samples that survive outages."""

from __future__ import annotations

import functools
import multiprocessing
import sqlite3
from collections import Counter
from datetime import UTC
from pathlib import Path

import pytest
from server_fixtures import at_once, make_v1_store
from sqlalchemy import text
from sqlalchemy.exc import SQLAlchemyError

from calib.result import CalibrationResult
from server.store import SCHEMA_VERSION, DecisionConflict, NotAcceptable, SessionEnd, Store, StoreError

RESULT = CalibrationResult.from_dict({"k": [1.01, 0.99, 1.02], "b": [0.5, -0.25, 0.125], "method": "closure",
          "uncertainty": {"k": [1e-4] * 3, "b": [1e-3] * 3}, "quality": {"score": 0.9}, "stages": []})


def _done(store: Store, sid: str, device: str = "dev-1") -> None:
    store.create_session(sid, device, "live", "connecting", "closure", "alice", "0.1.0", {"sensor_model": "ICM-20948"})
    store.finish_session(sid, SessionEnd("done", result=RESULT, passed=True))


def _decide(store: Store, sid: str, how: str, who: str) -> str:
    try:
        if how == "accept":
            store.accept(sid, who, RESULT)
        else:
            store.discard_session(sid, who)
        return how
    except DecisionConflict:
        return "conflict"


def _race(store: Store, sid: str, plan: list[str]) -> list[str]:
    """Run the decisions of ``plan`` at once in threads (released together by a barrier)."""
    return at_once([functools.partial(_decide, store, sid, how, f"op{i}") for i, how in enumerate(plan)], timeout_s=60)


def _check_history(store: Store, winners: dict[str, str], device: str = "dev-1") -> None:
    """One calibration row per accepted session, none for discarded ones, and the current one is accepted."""
    cals = store.calibrations(device)
    by_session = Counter(c.session_id for c in cals)
    accepted = {sid for sid, w in winners.items() if w == "accept"}
    assert set(by_session) == accepted and all(n == 1 for n in by_session.values())
    for sid, w in winners.items():
        assert store.session(sid)["decision"] == ("accepted" if w == "accept" else "discarded")
    current = store.current_calibration(device)
    assert current is None or store.session(current.session_id)["decision"] == "accepted"
    assert store.verify().ok


@pytest.mark.parametrize("plan", [["accept"] * 8, ["accept", "discard"] * 4])
def test_concurrent_decisions_in_threads_have_one_winner(store_url: str, plan: list[str]) -> None:
    store = Store(store_url)
    winners: dict[str, str] = {}
    for round_ in range(12):
        sid = f"{round_:02d}" + "a" * 30
        _done(store, sid)
        out = _race(store, sid, plan)
        wins = [o for o in out if o != "conflict"]
        assert len(wins) == 1, out
        winners[sid] = wins[0]
    _check_history(store, winners)
    assert store.calibration_count() == sum(w == "accept" for w in winners.values())


def _process_decider(url: str, sids: list[str], how: str, who: str, barrier: multiprocessing.synchronize.Barrier,
                     out: multiprocessing.queues.Queue) -> None:
    store = Store(url)  # each process opens the store itself: its own engine, its own connections
    for sid in sids:  # the processes are released together on each session in turn
        barrier.wait()
        out.put((sid, _decide(store, sid, how, who)))
    store.close()


def test_concurrent_decisions_in_processes_have_one_winner(store_url: str) -> None:
    store = Store(store_url)
    ctx = multiprocessing.get_context("spawn")
    plan = ["accept", "accept", "discard", "accept"]
    sids = [f"{round_:02d}" + "b" * 30 for round_ in range(4)]
    for sid in sids:
        _done(store, sid)
    barrier, q = ctx.Barrier(len(plan)), ctx.Queue()
    procs = [ctx.Process(target=_process_decider, args=(store_url, sids, how, f"p{i}", barrier, q)) for i, how in enumerate(plan)]
    for p in procs:
        p.start()
    out = [q.get(timeout=120) for _ in range(len(procs) * len(sids))]
    for p in procs:
        p.join(30)
    winners: dict[str, str] = {}
    for sid in sids:
        wins = [o for s, o in out if s == sid and o != "conflict"]
        assert len(wins) == 1, out
        winners[sid] = wins[0]
    _check_history(store, winners)


def test_the_loser_is_told_who_decided(store_url: str) -> None:
    store = Store(store_url)
    _done(store, "c" * 32)
    store.discard_session("c" * 32, "bob")
    with pytest.raises(DecisionConflict, match="discarded already by bob"):
        store.accept("c" * 32, "alice", RESULT)
    assert store.calibration_count() == 0


def test_one_calibration_per_session_is_a_database_constraint(store_url: str) -> None:
    store = Store(store_url)
    _done(store, "d" * 32)
    cal = store.accept("d" * 32, "alice", RESULT)
    cols = "id, device_id, session_id, k_x, k_y, k_z, b_x, b_y, b_z, result, method, software_version, source, operator, " \
           "computed_at, accepted_at, chain_seq, prev_hash, row_hash"
    vals = f"{cal.id + 100}, 'dev-1', '{'d' * 32}', 1, 1, 1, 0, 0, 0, '{{}}', 'closure', 'x', 'live', 'mallory', " \
           f"'2026-01-01', '2026-01-01', {cal.id + 100}, 'x', 'x'"
    with pytest.raises(SQLAlchemyError, match="(?i)unique|append-only"):
        with store.engine.begin() as conn:
            conn.execute(text(f"INSERT INTO calibrations ({cols}) VALUES ({vals})"))
    assert store.calibration_count() == 1


def test_sqlite_replace_cannot_rewrite_history(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite3"
    store = Store(f"sqlite:///{path}")
    _done(store, "e" * 32)
    store.archive_recording("e" * 32, b"t,gx,gy,gz\n0,0,0,0\n", 1)
    store.accept("e" * 32, "alice", RESULT)
    store.close()
    # an attacker with a plain sqlite3 connection (no pragmas of gyrocal's) tries REPLACE on every history table
    conn = sqlite3.connect(path)
    for table, where in (("calibrations", "1=1"), ("audit_log", "id = 1"), ("recordings", "1=1")):
        cols = [r[1] for r in conn.execute(f"PRAGMA table_info({table})")]
        row = conn.execute(f"SELECT {', '.join(cols)} FROM {table} WHERE {where} LIMIT 1").fetchone()
        forged = list(row)
        forged[cols.index("operator" if table != "recordings" else "encoding")] = "mallory"
        with pytest.raises(sqlite3.DatabaseError, match="append-only"):
            conn.execute(f"INSERT OR REPLACE INTO {table} ({', '.join(cols)}) VALUES ({', '.join('?' * len(cols))})", forged)
        with pytest.raises(sqlite3.DatabaseError, match="append-only"):
            conn.execute(f"REPLACE INTO {table} ({', '.join(cols)}) VALUES ({', '.join('?' * len(cols))})", forged)
    conn.close()
    store = Store(f"sqlite:///{path}")
    assert store.current_calibration("dev-1").operator == "alice"
    assert store.verify().ok


def test_postgres_truncate_and_upsert_are_refused(postgres) -> None:  # noqa: F811
    url = postgres.create_database()
    store = Store(url)
    _done(store, "f" * 32)
    store.accept("f" * 32, "alice", RESULT)
    for stmt in ("TRUNCATE audit_log", "TRUNCATE calibrations CASCADE", "TRUNCATE recordings",
                 "INSERT INTO audit_log (id, at, action, chain_seq, prev_hash, row_hash) SELECT id, at, 'x', chain_seq, 'x', 'x' "
                 "FROM audit_log LIMIT 1 ON CONFLICT (id) DO UPDATE SET operator = 'mallory'"):
        with pytest.raises(SQLAlchemyError, match="append-only"):
            with store.engine.begin() as conn:
                conn.execute(text(stmt))
    assert store.calibration_count() == 1 and store.verify().ok


def _tamper(store: Store, stmt: str) -> None:
    """What someone who can write the database file (or owns the tables) can do: drop the guards and edit."""
    from server.store import guards

    with store.engine.begin() as conn:
        guards.remove(conn)
        conn.execute(text(stmt))
        guards.install(conn)


@pytest.mark.parametrize("edit, chain, seq, problem", [
    ("UPDATE calibrations SET k_x = 1.5 WHERE chain_seq = 2", "calibrations", 2, "content does not match"),
    ("UPDATE audit_log SET operator = 'mallory' WHERE chain_seq = 3", "audit_log", 3, "content does not match"),
    ("DELETE FROM audit_log WHERE chain_seq = 4", "audit_log", 4, "missing"),
    ("DELETE FROM audit_log WHERE chain_seq = (SELECT MAX(chain_seq) FROM audit_log)", "audit_log", None, "removed from the end"),
    ("UPDATE recordings SET data = data || data WHERE chain_seq = 1", "recordings", 1, "content does not match"),
])
def test_tampering_is_evident_with_the_first_broken_link(store_url: str, edit: str, chain: str, seq: int | None,
                                                         problem: str) -> None:
    store = Store(store_url)
    for i in range(3):
        sid = f"{i}" * 32
        _done(store, sid)
        store.archive_recording(sid, f"t,gx,gy,gz\n{i},0,0,0\n".encode(), 1)
        store.accept(sid, "alice", RESULT)
    assert store.verify().ok
    if "||" in edit and store.dialect == "sqlite":
        edit = edit.replace("data || data", "CAST(data || data AS BLOB)")
    _tamper(store, edit)
    report = store.verify()
    assert not report.ok
    broken = report.broken
    assert broken.chain == chain and problem in broken.problem
    if seq is not None:
        assert broken.seq == seq


def test_an_accept_after_a_lost_end_write_stores_the_session_as_it_ended(store_url: str) -> None:
    store = Store(store_url)
    store.create_session("g" * 32, "dev-2", "live", "connecting", "closure", "alice", "0.1.0")
    # the end-of-session write failed (store outage); the accept carries the session as it ended
    from datetime import datetime

    ended = datetime(2026, 11, 24, 10, 0, 0, 123456, tzinfo=UTC)
    info = {"checks": [{"ok": True, "text": "k within 0.8-1.2"}], "turns": {"x": {"axis": "x"}}, "warnings": [{"code": "w"}],
            "lost_samples": 7}
    end = SessionEnd("done", result=RESULT, passed=True, info=info, ended_at=ended)
    store.accept("g" * 32, "alice", RESULT, end=end, recording_csv=b"t,gx,gy,gz\n0,0,0,0\n", n_samples=1)
    row = store.session("g" * 32)
    assert row["state"] == "done" and row["ended_at"] == ended.isoformat()
    for key, value in info.items():
        assert row["info"][key] == value
    actions = [e["action"] for e in store.audit_log("dev-2")]
    assert actions.count("session.done") == 1 and "calibration.accept" in actions
    assert store.current_calibration("dev-2").computed_at == ended
    # the late end write of the runner (if it comes) changes nothing
    store.finish_session("g" * 32, SessionEnd("failed", "x", "late"))
    assert store.session("g" * 32)["state"] == "done"


def test_a_failed_session_cannot_be_accepted_even_when_its_end_arrives_with_the_accept(store_url: str) -> None:
    store = Store(store_url)
    store.create_session("h" * 32, "dev-3", "live", "connecting", "closure", "alice", "0.1.0")
    with pytest.raises(NotAcceptable):
        store.accept("h" * 32, "alice", RESULT, end=SessionEnd("failed", "wrong_axis", "turned about y", passed=False))
    row = store.session("h" * 32)
    assert row["decision"] is None and row["ended_at"] is None  # nothing of the refused accept was kept
    assert store.calibration_count() == 0


def test_an_upload_without_a_sensor_cannot_become_a_calibration(store_url: str) -> None:
    store = Store(store_url)
    store.create_session("i" * 32, "dev-4", "upload", "computing", "closure", "alice", "0.1.0", {"source": "upload"})
    store.finish_session("i" * 32, SessionEnd("done", result=RESULT, passed=True))
    with pytest.raises(NotAcceptable, match="sensor_model"):
        store.accept("i" * 32, "alice", RESULT)
    cal = store.accept("i" * 32, "alice", RESULT, sensor_model="LSM9DS1", firmware="2.1")
    assert cal.source == "upload" and cal.sensor_model == "LSM9DS1" and cal.firmware == "2.1"


def test_a_crashed_sessions_spooled_samples_are_archived_at_restart(store_url: str) -> None:
    store = Store(store_url)
    store.create_session("j" * 32, "dev-5", "live", "turn_x", "closure", "alice", "0.1.0")
    store.spool_samples("j" * 32, 0, "t,gx,gy,gz,ax,ay,az,seq", b"0.0,1,2,3,0,0,1,0\n0.01,1,2,3,0,0,1,1\n", 2)
    store.spool_samples("j" * 32, 1, "t,gx,gy,gz,seq", b"0.02,4,5,6,2\n", 1)  # the accelerometer stopped
    store.close()
    again = Store(store_url)  # the service restarts after kill -9
    assert again.fail_unfinished_sessions("restarted") == 1
    data, _sha = again.recording("j" * 32)
    assert data.decode() == "t,gx,gy,gz,seq\n0.0,1,2,3,0\n0.01,1,2,3,1\n0.02,4,5,6,2\n"
    row = again.session("j" * 32)
    assert row["state"] == "failed" and row["info"]["samples"] == 3 and row["info"]["recovered_from_spool"]
    assert again.spooled_recording("j" * 32) is None and again.verify().ok


def test_a_crashed_sessions_binary_spool_is_archived_as_the_csv_its_samples_make(store_url: str) -> None:
    """The running session spools float64 rows (server.live.persistence.spool_rows); a crash leaves them to be archived
    as exactly the native CSV the whole recording would have been written as, beside an older CSV chunk."""
    import io

    import numpy as np

    from calib.io.readers import write_native_csv
    from calib.recording import RecordingMeta
    from server.live.buffer import SampleBuffer
    from server.live.persistence import spool_rows

    rng = np.random.default_rng(5)
    buf = SampleBuffer()
    t = np.arange(300) / 104.0 + 12.345
    buf.append(t, rng.normal(0, 3, (300, 3)), rng.normal(0, 1, (300, 3)), np.arange(300) + 70000)
    store = Store(store_url)
    store.create_session("k" * 32, "dev-6", "live", "turn_y", "closure", "alice", "0.1.0")
    for chunk, (lo, hi) in enumerate([(0, 104), (104, 250), (250, 300)]):
        store.spool_samples("k" * 32, chunk, *spool_rows(buf, lo, hi), hi - lo)
    store.close()
    again = Store(store_url)
    assert again.fail_unfinished_sessions("restarted") == 1
    data, _sha = again.recording("k" * 32)
    whole = io.StringIO()
    write_native_csv(buf.recording(RecordingMeta()), whole)
    assert data.decode() == whole.getvalue()
    assert again.session("k" * 32)["info"]["samples"] == 300 and again.verify().ok


def test_a_v1_store_is_migrated_and_its_history_chained(store_url: str) -> None:
    make_v1_store(store_url)
    store = Store(store_url)
    assert store.schema_version() == SCHEMA_VERSION == 7
    with store.engine.connect() as conn:  # stamped with its old version, then upgraded by Alembic to the head
        assert conn.execute(text("SELECT version_num FROM alembic_version")).scalar_one() == "0007"
        assert conn.execute(text("SELECT COUNT(*) FROM device_leases")).scalar_one() == 0
        assert conn.execute(text("SELECT COUNT(*) FROM kits")).scalar_one() == 0
    report = store.verify()
    assert report.ok and report.rows == {"recordings": 0, "calibrations": 2, "audit_log": 5}
    assert [c.source for c in store.calibrations("dev-1")] == ["upload", "live"]
    assert [c.identity for c in store.calibrations("dev-1")] == [None, None]  # v5: unknown for older calibrations
    _done(store, "k" * 32)
    store.accept("k" * 32, "bob", RESULT)  # new rows continue the migrated chains
    assert store.verify().ok and store.calibration_count() == 3
    store.record_held("dev-1", 3, "bob", written=True)  # v3: what the wearable holds
    assert store.device("dev-1")["held_calibration_id"] == 3 and store.verify().ok
    with pytest.raises(SQLAlchemyError, match="append-only"):
        with store.engine.begin() as conn:
            conn.execute(text("UPDATE calibrations SET k_x = 2"))


def test_gateways_starting_at_once_on_an_old_store_upgrade_it_once(store_url: str) -> None:
    """Four services open a v1 store at the same moment: one upgrades it (under the schema lock), the others find
    it done; the history is chained once, not four times."""
    make_v1_store(store_url)
    stores = at_once([lambda: Store(store_url)] * 4)
    for st in stores:
        assert st.schema_version() == SCHEMA_VERSION
    report = stores[0].verify()
    assert report.ok and report.rows == {"recordings": 0, "calibrations": 2, "audit_log": 5}
    with stores[0].engine.connect() as conn:
        assert conn.execute(text("SELECT version_num FROM alembic_version")).scalar_one() == "0007"
    for st in stores:
        st.close()


def test_a_store_that_cannot_be_opened_says_why(tmp_path: Path) -> None:
    with pytest.raises(StoreError, match="SQLite or PostgreSQL"):
        Store("mysql://u@h/db")


def test_the_postgres_service_role_cannot_get_round_the_guards(postgres) -> None:  # noqa: F811
    owner = postgres.create_database()
    service = postgres.service_url(owner)
    store = Store(service)
    assert not store.role_may_rewrite_history() and Store(owner).role_may_rewrite_history()
    _done(store, "m" * 32)
    store.accept("m" * 32, "alice", RESULT)  # the service works as this role
    for stmt in ("ALTER TABLE calibrations DISABLE TRIGGER ALL", "DROP TRIGGER calibrations_append_only ON calibrations",
                 "TRUNCATE audit_log", "DELETE FROM calibrations", "UPDATE audit_log SET operator = 'x'",
                 "ALTER TABLE audit_log OWNER TO CURRENT_USER", "SET session_replication_role = replica"):
        with pytest.raises(SQLAlchemyError, match="(?i)permission denied|must be owner|append-only"):
            with store.engine.begin() as conn:
                conn.execute(text(stmt))
    assert store.calibration_count() == 1 and store.verify().ok


def test_serve_refuses_to_connect_as_the_tables_owner(postgres, tmp_path: Path) -> None:  # noqa: F811
    import subprocess

    from server_fixtures import GYROCAL, ROOT

    owner = postgres.create_database()
    r = subprocess.run([*GYROCAL, "serve", "--db", owner, "--port", "0"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert "tables' owner" in r.stderr and "gyrocal store setup" in r.stderr and "Traceback" not in r.stderr


def test_store_verify_command_reports_the_first_broken_link(tmp_path: Path) -> None:
    import subprocess

    from server_fixtures import GYROCAL, ROOT

    url = f"sqlite:///{tmp_path / 's.sqlite3'}"
    store = Store(url)
    _done(store, "n" * 32)
    store.accept("n" * 32, "alice", RESULT)
    ok = subprocess.run([*GYROCAL, "store", "verify", "--db", url], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert ok.returncode == 0 and "intact" in ok.stdout
    _tamper(store, "UPDATE calibrations SET operator = 'mallory'")
    bad = subprocess.run([*GYROCAL, "store", "verify", "--db", url, "--json"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert bad.returncode == 4
    import json

    report = json.loads(bad.stdout)
    assert report["ok"] is False and report["first_broken_link"]["chain"] == "calibrations"
    assert report["first_broken_link"]["seq"] == 1


def test_store_verify_checks_each_recording_holds_the_samples_its_row_counts(store_url: str) -> None:
    """A recording written short hashes as well as a whole one: verify reads each recording against its row."""
    import json
    import subprocess

    from server_fixtures import GYROCAL, ROOT

    store = Store(store_url)
    csv = b"# sample_rate_rel_std: 0.001\nt,gx,gy,gz\n" + b"".join(f"{i / 100},0,0,0\n".encode() for i in range(40))
    _done(store, "r" * 32)
    store.archive_recording("r" * 32, csv, 40)
    assert store.verify().ok
    _done(store, "s" * 32)
    store.archive_recording("s" * 32, csv, 140)  # its row says 140 samples; 40 are there
    report = store.verify()
    assert not report.ok and report.broken is not None and report.broken.chain == "recordings"
    assert report.broken.problem == (f"the recording of session {'s' * 32} holds 40 samples where its row says 140 "
                                     "(it was cut short or padded when it was written)")
    bad = subprocess.run([*GYROCAL, "store", "verify", "--db", store_url, "--json"], cwd=ROOT, capture_output=True,
                         text=True, timeout=60)
    assert bad.returncode == 4 and json.loads(bad.stdout)["first_broken_link"]["seq"] == 2


def test_a_service_role_keeps_keeping_kits_once_a_store_from_before_kits_is_upgraded(postgres) -> None:  # noqa: F811
    """A store set up for a service role at revision 0006 (before kits): the owner's upgrade grants the role the new
    table, so the service, restarted as that role, keeps kits."""
    owner = postgres.create_database()
    service = postgres.service_url(owner)
    Store(service).close()
    with Store(owner).engine.begin() as conn:  # back to revision 0006: no kits table yet
        conn.execute(text("DROP TABLE kits"))
        conn.execute(text("UPDATE alembic_version SET version_num = '0006'"))
        conn.execute(text("UPDATE schema_info SET version = 6"))
    Store(owner).close()  # the owner upgrades it (as `gyrocal store setup` or a service started as the owner would)
    store = Store(service)
    _done(store, "p" * 32)
    store.create_kit("q" * 32, "alice", {"dev-1": "p" * 32})
    store.record_kit_outcome("q" * 32, None, [], None)
    assert store.kit("q" * 32)[0]["members"] == [{"device_id": "dev-1", "session_id": "p" * 32}]
