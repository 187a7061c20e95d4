"""Sign-ins under attack: how many guesses a minute get through, and how the service answers while flooded.

Run: .venv/bin/python bench/login_flood.py [--guess-s 65] [--flood-s 15]
Starts `gyrocal serve` on a fresh SQLite store with one operator, then:
1. 32 clients sign in with the right secret in a loop for --flood-s seconds while another measures GET /health;
2. a guesser sends wrong secrets for that operator as fast as it can for --guess-s seconds, from one address,
   and counts the attempts the service verified (401) and those it refused unverified (429).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
from local_service import free_port, scratch_dir

ROOT = Path(__file__).resolve().parents[1]
SECRET = "bench secret 0123456789"


def health_ms(base: str, seconds: float) -> list[float]:
    out: list[float] = []
    end = time.monotonic() + seconds
    with httpx.Client(base_url=base, timeout=30) as c:
        while time.monotonic() < end:
            t0 = time.perf_counter()
            c.get("/health")
            out.append(1000 * (time.perf_counter() - t0))
            time.sleep(0.05)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--guess-s", type=float, default=65.0)
    ap.add_argument("--flood-s", type=float, default=15.0)
    args = ap.parse_args()
    tmp = scratch_dir("gyrocal-login-")
    db = f"sqlite:///{tmp / 'store.sqlite3'}"
    gyrocal = [sys.executable, "-m", "calib.cli.main"]
    subprocess.run([*gyrocal, "operator", "--db", db, "add", "nurse", "--secret-stdin"], input=SECRET + "\n", text=True,
                   cwd=ROOT, check=True, capture_output=True)
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    proc = subprocess.Popen([*gyrocal, "serve", "--db", db, "--port", str(port), "--log-level", "warning"], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=dict(os.environ))
    try:
        for _ in range(200):
            try:
                if httpx.get(base + "/health", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                time.sleep(0.1)
        idle = health_ms(base, 3)
        stop = threading.Event()
        codes: list[int] = []
        workers = []
        for _ in range(32):
            def one() -> None:
                with httpx.Client(base_url=base, timeout=60) as c:
                    while not stop.is_set():
                        codes.append(c.post("/auth/login", json={"operator": "nurse", "secret": SECRET}).status_code)
            workers.append(threading.Thread(target=one))
        for w in workers:
            w.start()
        time.sleep(1.0)
        flooded = health_ms(base, args.flood_s)
        stop.set()
        for w in workers:
            w.join()
        q = lambda xs, p: sorted(xs)[int(p * (len(xs) - 1))]  # noqa: E731
        print(f"GET /health idle: median {statistics.median(idle):.1f} ms, p95 {q(idle, 0.95):.1f} ms")
        print(f"GET /health under 32 parallel sign-in loops: median {statistics.median(flooded):.1f} ms, "
              f"p95 {q(flooded, 0.95):.1f} ms; sign-ins {codes.count(200)} ok, {codes.count(429)} told to wait (429), "
              f"{len(codes) - codes.count(200) - codes.count(429)} other")
        verified, refused, first_minute = 0, 0, 0
        t0 = time.monotonic()
        with httpx.Client(base_url=base, timeout=30) as c:
            i = 0
            while time.monotonic() - t0 < args.guess_s:
                r = c.post("/auth/login", json={"operator": "nurse", "secret": f"guess number {i:06d}"})
                i += 1
                if r.status_code == 401:
                    verified += 1
                    first_minute += time.monotonic() - t0 <= 60.0
                else:
                    refused += 1
        print(f"guesser, {args.guess_s:.0f} s at full speed: {verified} guesses verified ({first_minute} in the first minute), "
              f"{refused} refused with 429 unverified")
    finally:
        proc.terminate()
        proc.wait(30)


if __name__ == "__main__":
    main()
