"""`/health` while 1,100 connections trickle their headers and never finish them, under a 1,024-file limit.

Starts `gyrocal serve` under `prlimit --nofile=1024:1024` (systemd's default for a service), opens ``--connections``
raw sockets that each send a request line and one more header line every second but never the blank line that ends
the headers (reopening any the service closes, as an attacker would), and meanwhile asks `/health` on a fresh
connection every 0.2 s. Reports the probes' latency, how many failed (5 s timeout), the log's size and how often it
says "Too many open files".

Usage: .venv/bin/python bench/half_open.py [--connections 1100] [--seconds 60] [--gyrocal PATH] [--json]
"""

from __future__ import annotations

import argparse
import json
import socket
import statistics
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import httpx
from local_service import free_port

ROOT = Path(__file__).resolve().parents[1]


def trickle(port: int, n: int, stop: threading.Event, counts: dict[str, int]) -> None:
    socks: list[socket.socket | None] = [None] * n
    while not stop.is_set():
        for i in range(n):
            s = socks[i]
            try:
                if s is None:
                    s = socket.create_connection(("127.0.0.1", port), timeout=2)
                    s.sendall(b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\n")
                    socks[i] = s
                    counts["opened"] += 1
                else:
                    s.sendall(b"X-Slow: 1\r\n")
            except OSError:
                counts["closed_by_service"] += s is not None
                if s is not None:
                    s.close()
                socks[i] = None
        stop.wait(1.0)
    for s in socks:
        if s is not None:
            s.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--connections", type=int, default=1100)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--gyrocal", default=str(ROOT / ".venv" / "bin" / "gyrocal"))
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--show-log", action="store_true", help="print the end of the service's log")
    args = ap.parse_args()

    import resource

    _, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, args.connections + 1024), hard))
    port = free_port()
    with tempfile.TemporaryDirectory() as tmp:
        log_path = Path(tmp) / "serve.log"
        with log_path.open("w") as log:
            proc = subprocess.Popen(["prlimit", "--nofile=1024:1024", args.gyrocal, "serve", "--port", str(port), "--db",
                                     f"sqlite:///{tmp}/store.sqlite3"], stdout=log, stderr=subprocess.STDOUT)
        base = f"http://127.0.0.1:{port}"
        try:
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                try:
                    if httpx.get(base + "/health", timeout=1).status_code == 200:
                        break
                except httpx.HTTPError:
                    time.sleep(0.2)
            stop = threading.Event()
            counts = {"opened": 0, "closed_by_service": 0}
            attack = threading.Thread(target=trickle, args=(port, args.connections, stop, counts), daemon=True)
            attack.start()
            time.sleep(3.0)
            latencies: list[float] = []
            failed = 0
            end = time.monotonic() + args.seconds
            while time.monotonic() < end:
                t0 = time.monotonic()
                try:
                    ok = httpx.get(base + "/health", timeout=5.0).status_code == 200
                except httpx.HTTPError:
                    ok = False
                if ok:
                    latencies.append(time.monotonic() - t0)
                else:
                    failed += 1
                time.sleep(0.2)
            stop.set()
            attack.join(30)
        finally:
            proc.terminate()
            proc.wait(30)
        text = log_path.read_text(errors="replace")
        if args.show_log:
            print(text[-6000:])
    ms = sorted(1000 * x for x in latencies)
    out: dict[str, Any] = {
        "connections": args.connections, "seconds": args.seconds, "probes": len(ms) + failed, "failed": failed,
        "p50_ms": round(statistics.median(ms), 1) if ms else None,
        "p95_ms": round(ms[int(0.95 * (len(ms) - 1))], 1) if ms else None,
        "max_ms": round(ms[-1], 1) if ms else None,
        "opened": counts["opened"], "closed_by_service": counts["closed_by_service"],
        "log_bytes": len(text), "too_many_open_files": text.count("Too many open files"),
    }
    if args.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k:>20}: {v}")


if __name__ == "__main__":
    main()
