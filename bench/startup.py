"""What a process costs: `gyrocal serve --mock 1` up (it answers /health) and stopped, its compute worker
included, and a command (`gyrocal operator --help`), in processor seconds (user + system) and wall seconds; and what
`make run`'s service (two simulated wearables whose clinicians follow the prompts) spends at rest, as a share of a core.

    .venv/bin/python bench/startup.py [--runs 3] [--idle-s 20]
"""

from __future__ import annotations

import argparse
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
from local_service import free_port, wait_until_up

GYROCAL = [sys.executable, "-m", "calib.cli.main"]


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def service_start(store: Path) -> tuple[float, float]:
    """(processor s, wall s until it answered) of one service start and stop."""
    cpu0, t0 = _children_cpu(), time.monotonic()
    port = free_port()
    proc = subprocess.Popen([*GYROCAL, "serve", "--port", str(port), "--db", f"sqlite:///{store}", "--mock", "1",
                             "--log-level", "warning"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    with httpx.Client(base_url=f"http://127.0.0.1:{port}") as c:
        wait_until_up(c, 60)
    up = time.monotonic() - t0
    proc.send_signal(signal.SIGTERM)
    proc.wait(30)
    return _children_cpu() - cpu0, up


def command() -> tuple[float, float]:
    cpu0, t0 = _children_cpu(), time.monotonic()
    subprocess.run([*GYROCAL, "operator", "--help"], check=True, stdout=subprocess.DEVNULL)
    return _children_cpu() - cpu0, time.monotonic() - t0


def idle_share(store: Path, seconds: float) -> float:
    """The share of one core `make run`'s service (and its compute worker) spends over ``seconds`` at rest."""
    port = free_port()
    proc = subprocess.Popen([*GYROCAL, "serve", "--port", str(port), "--db", f"sqlite:///{store}", "--mock", "2",
                             "--mock-scenario", "hand:careful,hand:bumps", "--log-level", "warning"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        with httpx.Client(base_url=f"http://127.0.0.1:{port}") as c:
            wait_until_up(c, 60)
        time.sleep(3.0)  # past the start's own work
        before = _tree_cpu(proc.pid)
        time.sleep(seconds)
        return (_tree_cpu(proc.pid) - before) / seconds
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(30)


def _tree_cpu(pid: int) -> float:
    """Processor seconds of ``pid`` and its children now running (Linux /proc)."""
    total, tick = 0.0, os.sysconf("SC_CLK_TCK")
    children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    for p in (pid, *map(int, children)):
        fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
        total += (int(fields[11]) + int(fields[12])) / tick
    return total


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--idle-s", type=float, default=20.0)
    args = ap.parse_args()
    runs = args.runs
    with tempfile.TemporaryDirectory() as tmp:
        print(f"make run's service at rest: {100 * idle_share(Path(tmp) / 'idle.sqlite3', args.idle_s):.1f} % of a core "
              f"(over {args.idle_s:g} s)")
    with tempfile.TemporaryDirectory() as tmp:
        starts = [service_start(Path(tmp) / f"s{i}.sqlite3") for i in range(runs)]
    commands = [command() for _ in range(runs)]
    for name, got in (("service start (--mock 1)", starts), ("command (operator --help)", commands)):
        cpu = sorted(c for c, _ in got)[len(got) // 2]
        wall = sorted(w for _, w in got)[len(got) // 2]
        print(f"{name:28s} median of {runs}: {cpu:.2f} s processor, {wall:.2f} s wall")


if __name__ == "__main__":
    main()
