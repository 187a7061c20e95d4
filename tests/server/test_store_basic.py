"""The store, against SQLite and a real PostgreSQL server: schema, append-only history, archive, audit."""

from __future__ import annotations

import gzip
from datetime import UTC, datetime, timedelta

import pytest
from sqlalchemy import create_engine, text
from sqlalchemy.exc import SQLAlchemyError

from calib.result import CalibrationResult
from server.auth import Authenticator, AuthError
from server.store import SCHEMA_VERSION, SessionEnd, Store, StoreError, sha256_hex

RESULT_JSON = {
    "k": [1.01, 0.99, 1.02],
    "b": [0.5, -0.25, 0.125],
    "method": "closure",
    "uncertainty": {"k": [1e-4, 1e-4, 1e-4], "b": [1e-3, 1e-3, 1e-3]},
    "quality": {"score": 0.9},
    "stages": [],
}
RESULT = CalibrationResult.from_dict(RESULT_JSON)


def _done_session(store: Store, sid: str, device: str = "dev-1", result: CalibrationResult | None = None, state: str = "done") -> None:
    store.create_session(sid, device, "live", "connecting", "closure", "alice", "0.1.0", {"sensor_model": "ICM-20948"})
    store.finish_session(sid, SessionEnd(state, result=result or RESULT, passed=state == "done"))


def test_schema_is_created_and_reopening_keeps_it(store_url: str) -> None:
    s = Store(store_url)
    assert s.schema_version() == SCHEMA_VERSION
    s.upsert_device("dev-1", name="wrist", transport="ble")
    s.close()
    again = Store(store_url)  # migrate() on an up-to-date store changes nothing
    assert again.schema_version() == SCHEMA_VERSION
    assert again.device("dev-1")["name"] == "wrist"
    again.close()


def test_the_revisions_read_from_their_file_names_are_alembics(store_url: str) -> None:
    """A new or up-to-date store is opened without Alembic, from the revision files' names: Alembic's own reading of
    the same files must agree, and a new store must be one Alembic sees at the head and would not upgrade."""
    from alembic.runtime.migration import MigrationContext
    from alembic.script import ScriptDirectory

    from server.store.schema import MIGRATIONS, head_revision, revisions

    scripts = ScriptDirectory(str(MIGRATIONS))
    assert [r.revision for r in reversed(list(scripts.walk_revisions()))] == revisions()
    assert scripts.get_current_head() == head_revision() == f"{SCHEMA_VERSION:04d}"
    s = Store(store_url)
    with s.engine.connect() as conn:
        assert MigrationContext.configure(conn).get_current_revision() == head_revision()
    s.close()


def test_newer_schema_is_refused(store_url: str) -> None:
    """A store a newer gyrocal upgraded (a revision this one does not know) is refused with what to do; so is one
    whose pre-Alembic schema version is newer. Nothing in it is changed."""
    s = Store(store_url)
    s.upsert_device("dev-1", name="wrist", transport="ble")
    with s.engine.begin() as conn:
        conn.execute(text("UPDATE alembic_version SET version_num = '0099'"))
    s.close()
    with pytest.raises(StoreError, match=r"schema revision 0099, newer than this gyrocal .*knows up to 0007.*upgrade gyrocal"):
        Store(store_url)
    eng = create_engine(store_url.replace("postgresql://", "postgresql+psycopg://"))
    with eng.begin() as conn:
        assert conn.execute(text("SELECT version_num FROM alembic_version")).scalar_one() == "0099"
        assert conn.execute(text("SELECT name FROM devices")).scalar_one() == "wrist"
        conn.execute(text("DROP TABLE alembic_version"))
        conn.execute(text("UPDATE schema_info SET version = :v"), {"v": SCHEMA_VERSION + 1})
    eng.dispose()
    with pytest.raises(StoreError, match="newer than this gyrocal"):
        Store(store_url)


def test_foreign_tables_are_refused(tmp_path) -> None:
    url = f"sqlite:///{tmp_path / 'other.sqlite3'}"
    from sqlalchemy import create_engine

    eng = create_engine(url)
    with eng.begin() as conn:
        conn.execute(text("CREATE TABLE devices (x int)"))
    eng.dispose()
    with pytest.raises(StoreError, match="not gyrocal's store"):
        Store(url)


def test_bad_url_is_a_clear_error() -> None:
    with pytest.raises(StoreError, match="not a database URL"):
        Store("not a url")


def test_history_is_append_only_and_current_is_latest(store_url: str) -> None:
    s = Store(store_url)
    _done_session(s, "a" * 32)
    first = s.accept("a" * 32, "alice", RESULT)
    second_result = CalibrationResult.from_dict({**RESULT_JSON, "k": [1.03, 0.98, 1.0]})
    _done_session(s, "b" * 32, result=second_result)
    second = s.accept("b" * 32, "bob", second_result)
    assert second.id != first.id
    assert s.current_calibration("dev-1").k == [1.03, 0.98, 1.0]
    history = s.calibrations("dev-1")
    assert [c.session_id for c in history] == ["b" * 32, "a" * 32]
    assert history[1].k == RESULT_JSON["k"] and history[1].operator == "alice"
    assert history[0].sensor_model == "ICM-20948"
    # the database itself refuses to change or delete history rows
    for stmt in ("UPDATE calibrations SET k_x = 2.0", "DELETE FROM calibrations", "DELETE FROM audit_log",
                 "UPDATE audit_log SET operator = 'mallory'"):
        with pytest.raises(SQLAlchemyError, match="append-only"):
            with s.engine.begin() as conn:
                conn.execute(text(stmt))
    assert s.current_calibration("dev-1").k == [1.03, 0.98, 1.0]
    assert len(s.calibrations("dev-1")) == 2


def test_a_session_is_accepted_once_and_discarded_ones_never_become_current(store_url: str) -> None:
    s = Store(store_url)
    _done_session(s, "c" * 32)
    s.accept("c" * 32, "alice", RESULT)
    with pytest.raises(StoreError, match="accepted already"):
        s.accept("c" * 32, "alice", RESULT)
    _done_session(s, "d" * 32, result=CalibrationResult.from_dict({**RESULT_JSON, "k": [0.9, 0.9, 0.9]}))
    s.discard_session("d" * 32, "alice")
    with pytest.raises(StoreError, match="discarded already"):
        s.accept("d" * 32, "alice", RESULT)
    assert s.current_calibration("dev-1").session_id == "c" * 32
    row = s.session("d" * 32)
    assert row["decision"] == "discarded" and row["decided_by"] == "alice"


def test_recordings_are_archived_compressed_with_their_hash(store_url: str) -> None:
    s = Store(store_url)
    _done_session(s, "e" * 32)
    csv = b"t,gx,gy,gz\n" + b"".join(f"{i / 100!r},0.1,0.2,0.3\n".encode() for i in range(5000))
    digest = s.archive_recording("e" * 32, csv, 5000)
    assert digest == sha256_hex(csv)
    data, got = s.recording("e" * 32)
    assert data == csv and got == digest
    with s.engine.connect() as conn:
        stored = conn.execute(text("SELECT data, size_bytes FROM recordings")).one()
    assert len(stored.data) < len(csv) / 3 and gzip.decompress(stored.data) == csv
    assert stored.size_bytes == len(csv)
    cal = s.accept("e" * 32, "alice", RESULT)
    assert cal.recording_sha256 == digest
    with pytest.raises(SQLAlchemyError, match="append-only"):
        with s.engine.begin() as conn:
            conn.execute(text("UPDATE recordings SET data = :d"), {"d": b"x"})


def test_accept_archives_a_recording_an_earlier_write_missed(store_url: str) -> None:
    s = Store(store_url)
    s.create_session("f" * 32, "dev-2", "live", "connecting", "closure", "alice", "0.1.0")
    # the end-of-session write failed: no result in the row, no recording archived
    cal = s.accept("f" * 32, "alice", RESULT, recording_csv=b"t,gx,gy,gz\n0,0,0,0\n", n_samples=1)
    assert cal.recording_sha256 == sha256_hex(b"t,gx,gy,gz\n0,0,0,0\n")
    assert s.session("f" * 32)["state"] == "done"
    assert s.recording("f" * 32)[1] == cal.recording_sha256


def test_unfinished_sessions_fail_after_a_restart_and_the_audit_log_says_who(store_url: str) -> None:
    s = Store(store_url)
    s.create_session("1" * 32, "dev-3", "live", "turn_y", "closure", "carol", "0.1.0")
    assert s.fail_unfinished_sessions("restarted") == 1
    row = s.session("1" * 32)
    assert row["state"] == "failed" and row["reason_code"] == "service_restarted"
    assert s.fail_unfinished_sessions("restarted") == 0
    actions = [(e["operator"], e["action"]) for e in s.audit_log("dev-3")]
    assert ("carol", "session.start") in actions and (None, "session.failed") in actions


def test_operators_tokens_and_revocation(store_url: str) -> None:
    s = Store(store_url)
    auth = Authenticator(s, api_token="env-token", token_ttl_s=3600)
    secret = auth.add_operator("alice")
    with pytest.raises(StoreError, match="exists already"):
        auth.add_operator("alice")
    with pytest.raises(AuthError, match="reserved"):
        auth.add_operator("api")
    with pytest.raises(AuthError, match="wrong secret"):
        auth.sign_in("alice", secret + "x")
    with pytest.raises(AuthError, match="wrong secret"):
        auth.sign_in("nobody", secret)
    token, expires = auth.sign_in("alice", secret)
    assert expires > datetime.now(UTC) + timedelta(minutes=59)
    assert auth.operator_for(token) == "alice"
    assert auth.operator_for("env-token") == "api"
    assert auth.operator_for("other") is None
    # the secret itself is stored hashed, never in clear
    with s.engine.connect() as conn:
        stored = conn.execute(text("SELECT secret_hash FROM operators")).scalar_one()
    assert secret not in stored and stored.startswith("scrypt$")
    auth.sign_out(token, "alice")
    assert auth.operator_for(token) is None
    token2, _ = auth.sign_in("alice", secret)
    s.disable_operator("alice")
    assert auth.operator_for(token2) is None
    with pytest.raises(AuthError):
        auth.sign_in("alice", secret)


def test_expired_tokens_are_refused(store_url: str) -> None:
    s = Store(store_url)
    auth = Authenticator(s, token_ttl_s=-1)
    secret = auth.add_operator("dave")
    token, _ = auth.sign_in("dave", secret)
    assert auth.operator_for(token) is None


def test_a_calibration_result_goes_into_the_store_and_comes_back_the_same(store_url: str) -> None:
    from calib.pipeline import calibrate
    from calib.simulator import simulate

    rec, _ = simulate(4, noise=0.05)
    result = calibrate(rec)
    assert result.sample_rate_hz == rec.fs and result.n_samples == len(rec)
    s = Store(store_url)
    _done_session(s, "r" * 32, result=result)
    stored = s.session("r" * 32)
    assert stored is not None
    back = CalibrationResult.from_dict(stored["result"])
    assert back.to_json() == result.to_json()
    cal = s.accept("r" * 32, "alice")
    assert cal.k == [float(v) for v in back.k] and cal.b == [float(v) for v in back.b]
    assert cal.uncertainty is not None and cal.uncertainty.model_dump() == result.to_json()["uncertainty"]
    assert cal.method == result.method
    assert cal.K is None and cal.K_std is None


def test_a_full_k_is_kept_with_its_uncertainty(store_url: str) -> None:
    K = [[1.01, 0.004, -0.002], [0.0, 0.99, 0.003], [0.0, 0.0, 1.02]]
    K_std = [[1e-4, 2e-3, 2e-3], [0.0, 1e-4, 2e-3], [0.0, 0.0, 1e-4]]
    result = CalibrationResult.from_dict({**RESULT_JSON, "K": K, "K_std": K_std, "quality": {"model": "upper-triangular"}})
    s = Store(store_url)
    _done_session(s, "k" * 32, result=result)
    cal = s.accept("k" * 32, "alice")
    assert cal.K == K and cal.K_std == K_std
    current = s.current_calibration("dev-1")
    assert current is not None and current.K_std == K_std


def test_a_kits_wearables_are_accepted_all_in_one_transaction_or_none(store_url: str) -> None:
    from server.store.calibrations import Acceptance

    s = Store(store_url)
    for sid, dev in (("k1" * 16, "dev-1"), ("k2" * 16, "dev-2"), ("k3" * 16, "dev-3")):
        _done_session(s, sid, dev)
    _done_session(s, "k4" * 16, "dev-4", state="failed")
    # one of them cannot be accepted: none is, and nothing of the others' is kept
    with pytest.raises(StoreError, match="ended failed"):
        s.accept_many([Acceptance("k1" * 16, RESULT), Acceptance("k4" * 16, RESULT)], "alice")
    assert s.current_calibration("dev-1") is None and s.session("k1" * 16)["decision"] is None
    records = s.accept_many([Acceptance(sid, RESULT) for sid in ("k1" * 16, "k2" * 16, "k3" * 16)], "alice")
    assert [r.device_id for r in records] == ["dev-1", "dev-2", "dev-3"]
    assert len({r.id for r in records}) == 3
    assert all(s.current_calibration(d).session_id == r.session_id for d, r in zip(("dev-1", "dev-2", "dev-3"), records,
                                                                                   strict=True))
    accepts = [e for e in s.audit_log(limit=50) if e["action"] == "calibration.accept"]
    assert sorted(e["device_id"] for e in accepts) == ["dev-1", "dev-2", "dev-3"]
    assert s.verify().ok  # the three rows chained one after the other in one transaction
    with pytest.raises(StoreError, match="accepted already"):
        s.accept_many([Acceptance("k2" * 16, RESULT)], "alice")


def test_a_kit_is_kept_with_its_wearables_sessions_and_how_they_followed_the_tray(store_url: str) -> None:
    """What a restarted service shows of a kit: its wearables' sessions in the kit's order (one never stored is left
    out), and once calibrated together, each wearable's consistency and who departed."""
    s = Store(store_url)
    members = {"dev-2": "m2" * 16, "dev-1": "m1" * 16, "dev-3": "m3" * 16}
    for dev in ("dev-2", "dev-1"):
        _done_session(s, members[dev], dev)
    s.create_kit("kit1" * 8, "alice", members, gateway="ward-3")
    assert s.kit("kit2" * 8) is None
    kit, sessions = s.kit("kit1" * 8)
    assert [m["device_id"] for m in kit["members"]] == ["dev-2", "dev-1", "dev-3"]
    assert [r["id"] for r in sessions] == [members["dev-2"], members["dev-1"]]
    assert kit["consistency"] is None and kit["departed"] == [] and kit["gateway"] == "ward-3" and kit["operator"] == "alice"
    s.record_kit_outcome("kit1" * 8, {"devices": {"dev-1": {"departed": True}}}, ["dev-1"], None)
    kit, _ = Store(store_url).kit("kit1" * 8)  # as another process reads it
    assert kit["departed"] == ["dev-1"] and kit["consistency"] == {"devices": {"dev-1": {"departed": True}}}
    start = [e for e in s.audit_log() if e["action"] == "kit.start"]
    assert len(start) == 1 and start[0]["session_id"] == "kit1" * 8 and start[0]["detail"]["sessions"] == members
    assert s.verify().ok
