"""A fleet under load: gateway processes sharing one PostgreSQL, every simulated wearable in a guided session at
once, and on each gateway a page following a session another gateway runs. Measures the fleet page's refresh
(GET /fleet) while they run, how long a calibration accepted on one gateway takes to show on another gateway's fleet
page (pushed through the database's notifications), and the database's load (commits and rows inserted per second,
WAL written, notifications per second).

Run: .venv/bin/python bench/fleet.py --db postgresql://owner@host/db [--gateways 3] [--wearables 20] [--speed 1]
The database must be empty; the gateways connect as its owner (--allow-db-owner: a benchmark, not a deployment).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

import httpx
import psycopg
from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
TOKEN = "bench-" + uuid.uuid4().hex
END = ("done", "failed", "cancelled")  # a session's end states


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _start(name: str, first: int, n: int, db: str, speed: float) -> tuple[subprocess.Popen[bytes], str]:
    port = _free_port()
    log = tempfile.NamedTemporaryFile(prefix=f"gyrocal-{name}-", suffix=".log", delete=False)
    cmd = [sys.executable, "-m", "calib.cli.main", "serve", "--port", str(port), "--db", db, "--allow-db-owner", "--log-level", "warning",
           "--gateway", name, "--mock", str(n), "--mock-first", str(first), "--mock-speed", str(speed), "--mock-rate", "104"]
    proc = subprocess.Popen(cmd, cwd=ROOT, env={**os.environ, "GYROCAL_API_TOKEN": TOKEN}, stdout=log, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}"
    for _ in range(600):
        try:
            if httpx.get(base + "/health", timeout=1).status_code == 200:
                return proc, base
        except httpx.HTTPError:
            time.sleep(0.1)
    raise SystemExit(f"gateway {name} did not start; see {log.name}")


def _db_stats(db: str) -> tuple[int, int, int]:
    with psycopg.connect(db.replace("postgresql+psycopg://", "postgresql://"), autocommit=True) as conn:
        q = "SELECT xact_commit, tup_inserted FROM pg_stat_database WHERE datname = current_database()"
        commits, inserted = conn.execute(q).fetchone()
        wal = conn.execute("SELECT pg_current_wal_lsn() - '0/0'::pg_lsn").fetchone()[0]
    return int(commits), int(inserted), int(wal)


class Notifications(threading.Thread):
    """Counts the fleet's notifications on the database (what every gateway's listener receives)."""

    def __init__(self, db: str) -> None:
        super().__init__(daemon=True)
        self.db, self.count, self.bytes, self.stop = db, 0, 0, threading.Event()

    def run(self) -> None:
        with psycopg.connect(self.db.replace("postgresql+psycopg://", "postgresql://"), autocommit=True) as conn:
            for channel in ("gyrocal_fleet", "gyrocal_follow", "gyrocal_session"):
                conn.execute(f"LISTEN {channel}")
            while not self.stop.is_set():
                for note in conn.notifies(timeout=0.5):
                    self.count += 1
                    self.bytes += len(note.payload)


class FleetPage(threading.Thread):
    """A fleet page's event stream (GET /fleet/events): when each device was first seen with a current calibration."""

    def __init__(self, base: str, headers: dict[str, str]) -> None:
        super().__init__(daemon=True)
        self.base, self.headers, self.current_at, self.views = base, headers, {}, 0

    def run(self) -> None:
        with contextlib.suppress(httpx.HTTPError):  # the gateway stopping at the end of the run
            with httpx.stream("GET", f"{self.base}/fleet/events", headers=self.headers, timeout=None) as r:
                for line in r.iter_lines():
                    if line.startswith("data:"):
                        now = time.perf_counter()
                        self.views += 1
                        for d in json.loads(line[5:])["devices"]:
                            if d["calibration"]["status"] == "current":
                                self.current_at.setdefault(d["id"], now)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--db", required=True, help="an empty PostgreSQL database, as its owner")
    ap.add_argument("--gateways", type=int, default=3)
    ap.add_argument("--wearables", type=int, default=20, help="simulated wearables per gateway")
    ap.add_argument("--speed", type=float, default=1.0, help="simulated time per wall-clock second (1: real time, 104 Hz)")
    args = ap.parse_args()
    headers = {"Authorization": f"Bearer {TOKEN}"}
    gws = [_start(f"gw-{g + 1}", 1 + g * args.wearables, args.wearables, args.db, args.speed) for g in range(args.gateways)]
    try:
        clients = [httpx.Client(base_url=base, headers=headers, timeout=60) for _, base in gws]
        started: list[tuple[int, str, str]] = []
        for g, c in enumerate(clients):
            for i in range(args.wearables):
                dev = f"mock-{1 + g * args.wearables + i}"
                r = c.post(f"/devices/{dev}/calibrate", json={})
                assert r.status_code == 202, r.text
                started.append((g, dev, r.json()["session_id"]))
        pages = [FleetPage(base, headers) for _, base in gws]
        for page in pages:
            page.start()
        notes = Notifications(args.db)
        notes.start()
        followers = []  # on each gateway, a page following a session of the next gateway
        for g in range(len(gws)):
            theirs = next(sid for h, _dev, sid in started if h == (g + 1) % len(gws))
            follower = threading.Thread(target=_follow, args=(gws[g][1], theirs, headers), daemon=True)
            follower.start()
            followers.append(follower)
        t0, s0, n0 = time.monotonic(), _db_stats(args.db), (notes.count, notes.bytes)
        refresh: list[float] = []
        stop = threading.Event()

        def poll() -> None:
            with httpx.Client(base_url=gws[0][1], headers=headers, timeout=60) as c:
                while not stop.is_set():
                    t = time.perf_counter()
                    assert c.get("/fleet").status_code == 200
                    refresh.append(time.perf_counter() - t)
                    time.sleep(0.5)

        poller = threading.Thread(target=poll, daemon=True)
        poller.start()
        ends: dict[str, str] = {}
        with tqdm(total=len(started), desc="sessions", unit="session") as bar:
            while len(ends) < len(started):
                for g, _dev, sid in started:
                    if sid not in ends:
                        state = clients[g].get(f"/sessions/{sid}").json()["state"]
                        if state in END:
                            ends[sid] = state
                            bar.update(1)
                time.sleep(1.0)
        stop.set()
        poller.join()
        t1, s1, n1 = time.monotonic(), _db_stats(args.db), (notes.count, notes.bytes)
        relayed = sum(not f.is_alive() for f in followers)
        appear: list[float] = []  # on the other gateway's fleet page (pushed)
        readable: list[float] = []  # through the other gateway's API (the same rows)
        for g, dev, sid in tqdm(started, desc="accepting", unit="session"):
            if ends[sid] != "done":
                continue
            other, other_api = pages[(g + 1) % len(pages)], clients[(g + 1) % len(clients)]
            time.sleep(0.3)  # one accept at a time, past the pages' refresh throttle: what one clinician's accept sees
            t = time.perf_counter()
            assert clients[g].post(f"/sessions/{sid}/accept").status_code == 200
            while other_api.get(f"/devices/{dev}/calibration").status_code != 200:
                time.sleep(0.002)
            readable.append(time.perf_counter() - t)
            while dev not in other.current_at:
                time.sleep(0.001)
            appear.append(other.current_at[dev] - t)
        dt = t1 - t0
        q = statistics.quantiles
        print(f"\n{args.gateways} gateways x {args.wearables} simulated wearables at 104 Hz (speed {args.speed:g}), "
              f"{len(started)} sessions: {sum(s == 'done' for s in ends.values())} done, sessions ran {dt:.0f} s")
        print(f"fleet page (GET /fleet, {len(refresh)} refreshes while all ran): median {statistics.median(refresh) * 1e3:.0f} ms, "
              f"p95 {q(refresh, n=20)[-1] * 1e3:.0f} ms")
        if len(appear) > 1:
            print(f"accepted on one gateway -> current on another gateway's fleet page (pushed): median "
                  f"{statistics.median(appear) * 1e3:.0f} ms, p95 {q(appear, n=20)[-1] * 1e3:.0f} ms (accept included)")
        if len(readable) > 1:
            print(f"accepted on one gateway -> GET /devices/{{id}}/calibration on another: median "
                  f"{statistics.median(readable) * 1e3:.0f} ms, p95 {q(readable, n=20)[-1] * 1e3:.0f} ms (accept included)")
        print(f"sessions followed live from another gateway: {relayed} of {len(followers)} streams reached the end")
        print(f"database during the sessions: {(s1[0] - s0[0]) / dt:.0f} commits/s, {(s1[1] - s0[1]) / dt:.0f} rows inserted/s, "
              f"WAL {(s1[2] - s0[2]) / dt / 1e6:.2f} MB/s, {(n1[0] - n0[0]) / dt:.1f} notifications/s "
              f"({(n1[1] - n0[1]) / dt / 1e3:.1f} kB/s)")
        print(f"fleet pages pushed {sum(p.views for p in pages)} views over the run")
        notes.stop.set()
    finally:
        for proc, _ in gws:
            proc.terminate()
        for proc, _ in gws:
            proc.wait(timeout=30)


def _follow(base: str, sid: str, headers: dict[str, str]) -> None:
    """Read a session's event stream (on a gateway that does not run it) to its end."""
    with httpx.stream("GET", f"{base}/sessions/{sid}/events", headers=headers, timeout=None) as r:
        for line in r.iter_lines():
            if line.startswith("data:") and json.loads(line[5:])["state"] in END:
                return


if __name__ == "__main__":
    main()
