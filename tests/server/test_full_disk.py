"""A full disk under the store (a real tmpfs that fills mid-session, SQLite on it): every finished calibration is
kept and written once space returns, the service says "full" where it said "unavailable", /health says it is
degraded, and no new session is started that could not be kept."""

from __future__ import annotations

import contextlib
import os
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from server_fixtures import RunningService, follow_events, wait_for

from server.auth import Authenticator
from server.store import Store

END = {"done", "failed", "cancelled"}
SECRET = "a-secret-of-carol"


def _the_full_disk_is_named(c: httpx.Client, done: str) -> None:
    """On a full disk a right secret is not answered 401 (a client reads that as a wrong secret), and a refused accept
    names the disk, not a class of gyrocal's (before: "could not be stored (StoreFull)")."""
    signed = c.post("/auth/login", json={"operator": "carol", "secret": SECRET})
    assert signed.status_code == 503 and "is full" in signed.json()["detail"], signed.text
    accepted = c.post(f"/sessions/{done}/accept")
    assert accepted.status_code == 503, accepted.text
    detail = accepted.json()["detail"]
    assert "could not be stored: the disk holding the store" in detail and "is full" in detail, detail
    assert "StoreFull" not in detail and "previous calibration stays current" in detail


@pytest.fixture
def small_disk() -> Iterator[Path]:
    """A 32 MB tmpfs of its own (needs root, as CI runs; `make test` does too)."""
    where = Path(tempfile.mkdtemp(prefix="gyrocal-disk-"))
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=32m", "tmpfs", str(where)], capture_output=True, text=True)
    assert mounted.returncode == 0, f"a test of a full disk mounts a small tmpfs, which needs root: {mounted.stderr}"
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], check=False)
        with contextlib.suppress(OSError):
            where.rmdir()


def _fill(disk: Path) -> Path:
    """Write a file until the disk is full; the file (delete it to free the space). Unbuffered: a buffered file kept
    what the full disk refused and raised "No space left on device" again when it was closed."""
    filler = disk / "filler"
    with filler.open("wb", buffering=0) as f:
        with contextlib.suppress(OSError):
            while True:
                f.write(b"\0" * 65536)
                f.flush()
                os.fsync(f.fileno())
    return filler


def test_sessions_ending_on_a_full_disk_are_kept_and_written_when_space_returns(small_disk: Path) -> None:
    url = f"sqlite:///{small_disk / 'store.sqlite3'}"
    Authenticator(Store(url)).add_operator("carol", SECRET)
    svc = RunningService(["--mock", "5", "--mock-speed", "4", "--mock-seed", "11"], url).start(60)
    try:
        with svc.client() as c:
            nearly = _fill(small_disk)  # no session is started that the store could not keep
            refused = c.post("/devices/mock-1/calibrate", json={})
            assert refused.status_code == 503 and "MB free, less than a calibration needs" in refused.json()["detail"]
            assert c.get("/health").json()["status"] == "degraded"
            nearly.unlink()
            sids = [c.post(f"/devices/mock-{i}/calibrate", json={}).json()["session_id"] for i in range(1, 6)]
        for sid in sids:
            follow_events(svc.base, sid, {"turn_x"}, timeout_s=60, last_event_id=0)
        filler = _fill(small_disk)  # the disk fills mid-session
        ends = {sid: follow_events(svc.base, sid, END, timeout_s=120, last_event_id=0)[-1] for sid in sids}
        assert sum(e["state"] == "done" for e in ends.values()) >= 3, ends

        with svc.client() as c:
            kept = wait_for(lambda: (r := c.get(f"/sessions/{sids[0]}").json())["stored"] is False and r, 20, "not stored")
            assert "is full" in kept["store_error"] and "written when space returns" in kept["store_error"]
            health = wait_for(lambda: (h := c.get("/health").json())["status"] == "degraded" and h, 20, "health degraded")
            assert any("could not be written to the store yet" in w and "is full" in w for w in health["warnings"]), health
            refused = c.post("/devices/mock-1/calibrate", json={})
            assert refused.status_code == 503 and "no calibration can be started" in refused.json()["detail"], refused.text
            assert "full" in refused.json()["detail"]
            signed = c.post("/auth/login", json={"operator": "nobody", "secret": "x" * 16})
            assert signed.status_code in (401, 503) and "unavailable (OperationalError)" not in signed.text
            _the_full_disk_is_named(c, next(sid for sid, e in ends.items() if e["state"] == "done" and e.get("passed")))

        filler.unlink()  # space returns: everything kept is written, without a restart
        with svc.client() as c:
            wait_for(lambda: c.get("/health").json()["status"] == "ok", 30, "health ok once space returned")
            store = Store(url)
            for sid, end in ends.items():
                row = store.session(sid)
                assert row is not None and row["state"] == end["state"] and row["reason_code"] == end.get("reason_code"), (row, end)
                assert store.recording(sid) is not None
                assert c.get(f"/sessions/{sid}").json()["stored"] is True
            done = next(sid for sid, e in ends.items() if e["state"] == "done" and e.get("passed"))
            assert c.post(f"/sessions/{done}/accept").status_code == 200
            assert store.verify().ok
    finally:
        svc.stop()
    assert "Traceback" not in svc.output()


def test_a_full_disk_under_postgresql_is_named_and_nothing_is_lost(small_disk: Path, postgres) -> None:  # noqa: ANN001
    """The store's database in a tablespace on the small tmpfs, which fills mid-session: PostgreSQL refuses with
    SQLSTATE 53100 (disk_full), and the service says the disk is full, keeps every finished session and writes it once
    space returns, as on SQLite. (A full disk under PostgreSQL's own write-ahead log is another matter: the server
    stops itself, and the service sees the store unavailable.)"""
    import psycopg

    where = small_disk / "tablespace"
    where.mkdir()
    subprocess.run(["chown", "postgres:postgres", str(where)], check=True)
    name = "gyrocal_full_" + os.urandom(4).hex()
    with psycopg.connect(f"host=127.0.0.1 port={postgres.port} user=postgres dbname=postgres", autocommit=True) as conn:
        conn.execute(f"CREATE TABLESPACE {name} LOCATION '{where}'")
        conn.execute(f'CREATE DATABASE "{name}" TABLESPACE {name}')
    owner = postgres.url(name)
    Authenticator(Store(owner)).add_operator("carol", SECRET)
    svc = RunningService(["--mock", "4", "--mock-speed", "4", "--mock-seed", "11"], postgres.service_url(owner)).start(60)
    filler = None
    try:
        with svc.client() as c:
            sids = [c.post(f"/devices/mock-{i}/calibrate", json={}).json()["session_id"] for i in range(1, 5)]
        for sid in sids:
            follow_events(svc.base, sid, {"turn_x"}, timeout_s=60, last_event_id=0)
        filler = _fill(small_disk)
        ends = {sid: follow_events(svc.base, sid, END, timeout_s=120, last_event_id=0)[-1] for sid in sids}
        assert sum(e["state"] == "done" for e in ends.values()) >= 2, ends
        with svc.client() as c:
            kept = wait_for(lambda: (r := c.get(f"/sessions/{sids[0]}").json())["stored"] is False and r, 20, "not stored")
            assert "is full" in kept["store_error"] and "written when space returns" in kept["store_error"], kept
            health = wait_for(lambda: (h := c.get("/health").json())["status"] == "degraded" and h, 20, "health degraded")
            assert any("is full" in w for w in health["warnings"]), health
            _the_full_disk_is_named(c, next(sid for sid, e in ends.items() if e["state"] == "done" and e.get("passed")))
        filler.unlink()
        filler = None
        with svc.client() as c:
            wait_for(lambda: c.get("/health").json()["status"] == "ok", 30, "health ok once space returned")
            store = Store(owner)
            for sid, end in ends.items():
                row = store.session(sid)
                assert row is not None and row["state"] == end["state"], (row, end)
                assert store.recording(sid) is not None
            done = next(sid for sid, e in ends.items() if e["state"] == "done" and e.get("passed"))
            assert c.post(f"/sessions/{done}/accept").status_code == 200
            assert store.verify().ok
            store.close()
    finally:
        if filler is not None:
            filler.unlink()
        svc.stop()
        with psycopg.connect(f"host=127.0.0.1 port={postgres.port} user=postgres dbname=postgres", autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
            conn.execute(f"DROP TABLESPACE IF EXISTS {name}")
    assert "Traceback" not in svc.output()
