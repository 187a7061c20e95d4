"""Calibrations through a full disk: how many finished sessions the store keeps, and how soon after space returns.

Mounts a 32 MB tmpfs (root), starts `gyrocal serve --mock N` with its SQLite store there, starts a guided session on
every wearable, fills the disk once all are turning, waits for every session to end, frees the space, and reports
how each ended on the service, what the store holds before and after, what /health and a new session said while
full, and how long the store took to catch up.

Usage: sudo .venv/bin/python bench/full_disk.py [--devices 5] [--speed 4] [--json]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
from local_service import free_port

ROOT = Path(__file__).resolve().parents[1]
END = ("done", "failed", "cancelled")
TOKEN = "bench-full-disk-token"


def fill(disk: Path) -> Path:
    filler = disk / "filler"
    with filler.open("wb") as f, contextlib.suppress(OSError):
        while True:
            f.write(b"\0" * 65536)
            f.flush()
            os.fsync(f.fileno())
    return filler


def wait(pred: Any, timeout_s: float) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with contextlib.suppress(httpx.HTTPError):
            if got := pred():
                return got
        time.sleep(0.2)
    raise SystemExit("timed out")


def stored(url: str, sids: list[str]) -> dict[str, Any]:
    import sqlite3

    con = sqlite3.connect(url.removeprefix("sqlite:///"))
    try:
        states = dict(con.execute(f"SELECT id, state FROM sessions WHERE id IN ({','.join('?' * len(sids))})", sids).fetchall())
        recs = {r[0] for r in con.execute("SELECT session_id FROM recordings").fetchall()}
    finally:
        con.close()
    return {"states": [states.get(s) for s in sids], "recordings": sum(s in recs for s in sids)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--devices", type=int, default=5)
    ap.add_argument("--speed", type=float, default=4.0)
    ap.add_argument("--gyrocal", default=str(ROOT / ".venv" / "bin" / "gyrocal"))
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    disk = Path(tempfile.mkdtemp(prefix="gyrocal-bench-disk-"))
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=32m", "tmpfs", str(disk)], check=True)
    port = free_port()
    url = f"sqlite:///{disk}/store.sqlite3"
    log = (Path(tempfile.gettempdir()) / "gyrocal-bench-full-disk.log").open("w")
    proc = subprocess.Popen([args.gyrocal, "serve", "--port", str(port), "--db", url, "--mock", str(args.devices),
                             "--mock-speed", f"{args.speed:g}", "--log-level", "warning"],
                            env={**os.environ, "GYROCAL_API_TOKEN": TOKEN}, stdout=log, stderr=subprocess.STDOUT)
    out: dict[str, Any] = {}
    try:
        c = httpx.Client(base_url=f"http://127.0.0.1:{port}", headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30)
        wait(lambda: c.get("/health").status_code == 200, 60)
        sids = [c.post(f"/devices/mock-{i}/calibrate", json={}).json()["session_id"] for i in range(1, args.devices + 1)]
        wait(lambda: all(c.get(f"/sessions/{s}").json()["state"] == "turn_x" for s in sids), 120)
        filler = fill(disk)
        ends = wait(lambda: (e := [c.get(f"/sessions/{s}").json() for s in sids]) and all(x["state"] in END for x in e) and e, 300)
        time.sleep(1.0)
        out["ended_on_the_service"] = [e["state"] for e in ends]
        out["stored_while_full"] = stored(url, sids)
        out["health_while_full"] = c.get("/health").json()["status"]
        refused = c.post("/devices/mock-1/calibrate", json={})
        out["new_session_while_full"] = f"{refused.status_code}: {refused.json()['detail'][:120]}"
        filler.unlink()
        t0 = time.monotonic()
        wait(lambda: c.get("/health").json()["status"] == "ok", 60)
        out["written_after_space_returned_s"] = round(time.monotonic() - t0, 1)
        out["stored_after"] = stored(url, sids)
    finally:
        proc.terminate()
        proc.wait(30)
        subprocess.run(["umount", "-l", str(disk)], check=False)
        with contextlib.suppress(OSError):
            disk.rmdir()
    if args.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k:>32}: {v}")


if __name__ == "__main__":
    main()
