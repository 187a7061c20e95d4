"""A busy clinic: tablets starting and cancelling calibrations at once, each on its own simulated wearable.

Starts `gyrocal serve --mock N` (SQLite in a scratch directory, or --db URL), then N clients, each in a loop for
--seconds: start a calibration on its wearable, follow its first events, cancel it, wait until the service has
written it, start again. Reports how many starts were refused (and why), and how many spooled sample rows the
ended sessions left in the store. Run it from any checkout: the service is the checkout's own (`-m calib.cli.main`
from the current directory).

Usage: .venv/bin/python bench/busy_clinic.py [--tablets 4] [--seconds 40] [--db URL] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
import uuid
from collections import Counter
from pathlib import Path
from typing import Any

import httpx
from local_service import free_port, scratch_dir, wait_until_up
from sqlalchemy import create_engine, text


def tablet(base: str, token: str, device: str, until: float, out: list[str]) -> None:
    """One tablet's loop; appends "202" or the refusal (status and detail) of every start to ``out``."""
    with httpx.Client(base_url=base, headers={"Authorization": f"Bearer {token}"}, timeout=30) as c:
        while time.monotonic() < until:
            r = c.post(f"/devices/{device}/calibrate", json={})
            if r.status_code != 202:
                out.append(f"{r.status_code} {r.json().get('detail', '')[:120]}")
                time.sleep(0.2)
                continue
            out.append("202")
            sid = r.json()["session_id"]
            time.sleep(0.3)  # the page shows its first steps
            c.post(f"/sessions/{sid}/cancel")
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and not c.get(f"/sessions/{sid}").json().get("stored"):
                time.sleep(0.05)


def spooled_rows(url: str) -> int:
    eng = create_engine(url.replace("postgresql://", "postgresql+psycopg://"))
    try:
        with eng.connect() as conn:
            return int(conn.execute(text("SELECT count(*) FROM session_samples")).scalar_one())
    finally:
        eng.dispose()


def run(args: argparse.Namespace) -> dict[str, Any]:
    token = uuid.uuid4().hex
    port = free_port()
    db = args.db or f"sqlite:///{scratch_dir('gyrocal-bench-clinic-')}/store.sqlite3"
    cmd = [sys.executable, "-m", "calib.cli.main", "serve", "--port", str(port), "--db", db, "--mock", str(args.tablets),
           "--mock-speed", "4", "--log-level", "warning"]
    proc = subprocess.Popen(cmd, cwd=Path.cwd(), env={**os.environ, "GYROCAL_API_TOKEN": token},
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{port}"
    answers: list[list[str]] = [[] for _ in range(args.tablets)]
    try:
        with httpx.Client(base_url=base) as c:
            wait_until_up(c, 60)
        until = time.monotonic() + args.seconds
        threads = [threading.Thread(target=tablet, args=(base, token, f"mock-{i + 1}", until, answers[i]))
                   for i in range(args.tablets)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        time.sleep(2.0)  # the last writes land
        left = spooled_rows(db)
    finally:
        proc.terminate()
        proc.wait(30)
    every = [a for tablet_answers in answers for a in tablet_answers]
    refused = Counter(a for a in every if a != "202")
    return {"tablets": args.tablets, "seconds": args.seconds, "starts": len(every), "refused": sum(refused.values()),
            "refusals": dict(refused), "spooled_rows_left": left}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--tablets", type=int, default=4)
    p.add_argument("--seconds", type=float, default=40.0)
    p.add_argument("--db", default=None, help="a store URL (default: SQLite in a scratch directory)")
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    report = run(args)
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"{report['tablets']} tablets for {report['seconds']:g} s: {report['starts']} starts, {report['refused']} refused; "
          f"{report['spooled_rows_left']} spooled rows left behind")
    for why, n in sorted(report["refusals"].items(), key=lambda kv: -kv[1]):
        print(f"  {n} x {why}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
