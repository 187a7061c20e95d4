"""Memory under session churn: guided sessions started and cancelled, one after another on every wearable.

Starts `gyrocal serve --mock N`, then on each wearable in turn starts a guided session and cancels it, ``--sessions``
times in all, and reports the service's resident memory (VmRSS) every ``--every`` sessions and once settled (the
service keeps the newest 200 finished sessions for their pages, so memory should stop growing there).

Usage: .venv/bin/python bench/session_churn.py [--sessions 2000] [--devices 4] [--gyrocal PATH] [--json]
"""

from __future__ import annotations

import argparse
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
TOKEN = "bench-session-churn-token"


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=2000)
    ap.add_argument("--devices", type=int, default=4)
    ap.add_argument("--every", type=int, default=200)
    ap.add_argument("--gyrocal", default=str(ROOT / ".venv" / "bin" / "gyrocal"))
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    port = free_port()
    with tempfile.TemporaryDirectory() as tmp:
        proc = subprocess.Popen([args.gyrocal, "serve", "--port", str(port), "--db", f"sqlite:///{tmp}/store.sqlite3",
                                 "--mock", str(args.devices), "--mock-speed", "5", "--log-level", "warning"],
                                env={**os.environ, "GYROCAL_API_TOKEN": TOKEN}, stdout=subprocess.DEVNULL,
                                stderr=subprocess.STDOUT)
        out: dict[str, Any] = {"rss_mb": {}}
        try:
            c = httpx.Client(base_url=f"http://127.0.0.1:{port}", headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30)
            while True:
                try:
                    if c.get("/health").status_code == 200:
                        break
                except httpx.HTTPError:
                    time.sleep(0.2)
            out["rss_mb"][0] = round(rss_mb(proc.pid), 1)
            t0, done = time.monotonic(), 0
            while done < args.sessions:
                r = c.post(f"/devices/mock-{done % args.devices + 1}/calibrate", json={})
                if r.status_code != 202:  # the wearable is still being let go by the last session
                    time.sleep(0.02)
                    continue
                c.post(f"/sessions/{r.json()['session_id']}/cancel")
                done += 1
                if done % args.every == 0:
                    out["rss_mb"][done] = round(rss_mb(proc.pid), 1)
            out["seconds"] = round(time.monotonic() - t0, 1)
            time.sleep(7)
            out["settled_mb"] = round(rss_mb(proc.pid), 1)
        finally:
            proc.terminate()
            proc.wait(30)
    first = out["rss_mb"].get(args.every)
    out["growth_after_first_mb"] = None if first is None else round(out["settled_mb"] - first, 1)
    if args.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k:>22}: {v}")


if __name__ == "__main__":
    main()
