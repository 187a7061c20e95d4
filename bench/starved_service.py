"""Sessions on a starved service: does a late service ever blame the clinician?

Starts `gyrocal serve --mock N` (scripted hands at real speed: they turn when their script says, whatever the page
shows, so a turn the service throws away never comes again), starts a guided session on every wearable, then holds
the service to a share of one core until every session has ended, and reports how each ended: its state, reason,
the warnings it gave, samples lost and how long the service itself was late.

Two ways to starve it:
- ``--quota PCT``: a CPU quota (cgroup v2 ``cpu.max`` or v1 ``cpu.cfs_quota_us``; needs root), the service held to
  PCT % of one core, as a container's or a systemd unit's CPUQuota holds it;
- ``--stop S``: SIGSTOP the process for S seconds once the first session is mid-turn (a stalled process).

Usage: .venv/bin/python bench/starved_service.py [--devices 10] [--quota 2.5 | --stop 3] [--gyrocal PATH] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

import httpx
from local_service import free_port, scratch_dir

ROOT = Path(__file__).resolve().parents[1]
END = ("done", "failed", "cancelled")
CLINICIAN_REASONS = {"not_still", "no_motion", "moved_during_pause", "wrong_axis", "too_fast", "turn_incomplete",
                     "turn_too_far", "turn_too_long"}
TOKEN = "bench-starved-service-token"


class CpuQuota:
    """A cgroup that holds its processes to a share of one core (v2 cpu.max, else v1 cpu.cfs_quota_us)."""

    def __init__(self) -> None:
        v2, v1 = Path("/sys/fs/cgroup/cgroup.controllers"), Path("/sys/fs/cgroup/cpu")
        name = f"gyrocal-bench-{os.getpid()}"
        if v2.is_file() and "cpu" in v2.read_text().split():
            self.dir, self.v2 = Path("/sys/fs/cgroup") / name, True
        elif v1.is_dir():
            self.dir, self.v2 = v1 / name, False
        else:
            raise SystemExit("no cgroup cpu controller here: use --stop instead of --quota")
        self.dir.mkdir()

    def add(self, pid: int) -> None:
        (self.dir / ("cgroup.procs" if self.v2 else "tasks")).write_text(str(pid))

    def hold(self, percent: float | None) -> None:
        period = 100_000
        if self.v2:
            (self.dir / "cpu.max").write_text("max" if percent is None else f"{int(period * percent / 100)} {period}")
        else:
            (self.dir / "cpu.cfs_period_us").write_text(str(period))
            (self.dir / "cpu.cfs_quota_us").write_text("-1" if percent is None else str(int(period * percent / 100)))

    def remove(self) -> None:
        self.hold(None)
        for _ in range(50):
            try:
                self.dir.rmdir()
                return
            except OSError:
                time.sleep(0.1)


def run(devices: int, quota: float | None, stop_s: float | None, gyrocal: str) -> list[dict[str, Any]]:
    port = free_port()
    db = scratch_dir("gyrocal-starved-") / "store.sqlite3"
    cgroup = CpuQuota() if quota is not None else None
    env = {**os.environ, "GYROCAL_API_TOKEN": TOKEN}
    proc = subprocess.Popen([gyrocal, "serve", "--mock", str(devices), "--port", str(port), "--db", f"sqlite:///{db}",
                             "--log-level", "warning"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    if cgroup is not None:
        cgroup.add(proc.pid)
    c = httpx.Client(base_url=f"http://127.0.0.1:{port}", headers={"Authorization": f"Bearer {TOKEN}"}, timeout=300)
    try:
        for _ in range(300):
            try:
                if c.get("/health").status_code == 200:
                    break
            except httpx.HTTPError:
                time.sleep(0.2)
        sids = [c.post(f"/devices/mock-{i}/calibrate").json()["session_id"] for i in range(1, devices + 1)]
        if cgroup is not None:
            cgroup.hold(quota)
        if stop_s is not None:
            while not any(c.get(f"/sessions/{s}").json().get("phase") == "turning" for s in sids):
                time.sleep(0.2)
            proc.send_signal(signal.SIGSTOP)
            time.sleep(stop_s)
            proc.send_signal(signal.SIGCONT)
        ended: dict[str, dict[str, Any]] = {}
        deadline = time.monotonic() + 900
        while len(ended) < len(sids) and time.monotonic() < deadline:
            for sid in sids:
                if sid not in ended:
                    snap = c.get(f"/sessions/{sid}").json()
                    if snap.get("state") in END:
                        ended[sid] = snap
            time.sleep(1.0)
        return [ended.get(sid, {"session_id": sid, "state": "still running"}) for sid in sids]
    finally:
        if cgroup is not None:
            cgroup.hold(None)
        proc.send_signal(signal.SIGTERM)
        proc.wait(30)
        if cgroup is not None:
            cgroup.remove()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--devices", type=int, default=10)
    how = ap.add_mutually_exclusive_group(required=True)
    how.add_argument("--quota", type=float, help="percent of one core the service may use")
    how.add_argument("--stop", type=float, help="seconds the service's process is stopped mid-turn")
    ap.add_argument("--gyrocal", default=str(Path(sys.executable).with_name("gyrocal")), help="the gyrocal to run")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    snaps = run(args.devices, args.quota, args.stop, args.gyrocal)
    rows = [{"device": s.get("device_id"), "state": s.get("state"), "reason_code": s.get("reason_code"),
             "warnings": [w["code"] for w in s.get("warnings", [])], "lost_samples": s.get("lost_samples"),
             "service_late_s": s.get("service_late_s")} for s in snaps]
    blamed = [r for r in rows if r["reason_code"] in CLINICIAN_REASONS]
    summary = {"devices": args.devices, "quota_pct": args.quota, "stop_s": args.stop,
               "ended": dict(Counter(f"{r['state']}:{r['reason_code']}" if r["reason_code"] else r["state"] for r in rows)),
               "clinician_blamed": len(blamed), "sessions": rows}
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        for r in rows:
            print(f"{r['device']}: {r['state']} {r['reason_code'] or ''} warnings={','.join(r['warnings'])} lost={r['lost_samples']} "
                  f"service_late_s={r['service_late_s']}")
        print(f"ended: {summary['ended']}; sessions that blamed the clinician: {len(blamed)} of {len(rows)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
