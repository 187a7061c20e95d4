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

import pytest
from server_fixtures import RunningService, follow_events, wait_for

from server.store import Store

END = {"done", "failed", "cancelled"}


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
