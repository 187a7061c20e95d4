"""How fast stage events reach the wizard: N simulated wearables streaming, one SSE client each.

Starts `gyrocal serve --mock N --mock-rate R` in a subprocess, starts a guided session on every
simulated wearable (each performs the protocol in real time), follows every session's Server-Sent
Events and measures, for each event, the time from the production of the samples that caused it
(the last sample of the batch the service was processing) to its arrival at the client.

The device clock of a simulated wearable runs at exactly --mock-speed times wall time, so a sample's
production time is W0 + t_device / speed; W0 is estimated per session as the smallest
(server receive time - t_device / speed) over all its events, which makes the end-to-end figures
slightly optimistic by the fastest delivery (microseconds in process). The service-side part
(client arrival - service receive time, same clock) is reported too.

Usage: .venv/bin/python bench/sse_latency.py [--devices 20] [--rate 562.5] [--json]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import time
import uuid
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from local_service import free_port, scratch_dir

ROOT = Path(__file__).resolve().parents[1]
STAGE_EVENTS = {"state", "prompt", "warning"}  # what the stage detector causes (not the rate-limited live feed)
END = {"done", "failed", "cancelled"}


def _stat(pid: int) -> list[str] | None:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None


def cpu_seconds(pid: int) -> dict[int, float]:
    """User + system CPU time (s) of a process and of its living descendants (the estimator's workers)."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and (st := _stat(int(entry.name))) is not None:
            parents[int(entry.name)] = int(st[1])
    family, grew = {pid}, True
    while grew:
        new = {p for p, pp in parents.items() if pp in family} - family
        family |= new
        grew = bool(new)
    ticks = os.sysconf("SC_CLK_TCK")
    out = {}
    for p in family:
        st = _stat(p)
        if st is not None:
            out[p] = (int(st[11]) + int(st[12])) / ticks
    return out


async def follow(client: httpx.AsyncClient, sid: str, out: list[dict[str, Any]]) -> None:
    async with client.stream("GET", f"/sessions/{sid}/events", params={"last_event_id": 0}, timeout=None) as r:
        data: str | None = None
        name = "message"
        async for line in r.aiter_lines():
            if line == "":
                if data is not None:
                    snap = json.loads(data)
                    out.append({"recv": time.time(), "event": name, "state": snap["state"], "caused_by": snap.get("caused_by"),
                                "reason_code": snap.get("reason_code")})
                    if snap["state"] in END:
                        return
                data, name = None, "message"
            elif line.startswith("data:"):
                data = line[5:].strip()
            elif line.startswith("event:"):
                name = line[6:].strip()


async def run(args: argparse.Namespace) -> dict[str, Any]:
    token = uuid.uuid4().hex
    port = free_port()
    tmp = scratch_dir("gyrocal-bench-")
    cmd = [sys.executable, "-m", "calib.cli.main", "serve", "--port", str(port), "--db", f"sqlite:///{tmp}/bench.sqlite3",
           "--mock", str(args.devices), "--mock-rate", str(args.rate), "--mock-speed", str(args.speed),
           "--mock-seed", str(args.seed), "--log-level", "warning"]
    proc = subprocess.Popen(cmd, cwd=ROOT, env={**os.environ, "GYROCAL_API_TOKEN": token},
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    base = f"http://127.0.0.1:{port}"
    try:
        async with httpx.AsyncClient(base_url=base, headers={"Authorization": f"Bearer {token}"}, timeout=30) as client:
            for _ in range(300):
                try:
                    if (await client.get("/health")).status_code == 200:
                        break
                except httpx.HTTPError:
                    await asyncio.sleep(0.1)
            else:
                raise RuntimeError(f"the service did not start: {proc.stderr.read() if proc.stderr else ''}")
            sids = []
            for i in range(1, args.devices + 1):
                r = await client.post(f"/devices/mock-{i}/calibrate", json={})
                r.raise_for_status()
                sids.append(r.json()["session_id"])
            events: dict[str, list[dict[str, Any]]] = {sid: [] for sid in sids}
            cpu0, wall0 = cpu_seconds(proc.pid), time.monotonic()
            client_cpu0 = time.process_time()
            await asyncio.wait_for(asyncio.gather(*(follow(client, sid, events[sid]) for sid in sids)), timeout=args.timeout)
            cpu1, wall1 = cpu_seconds(proc.pid), time.monotonic()
            # workers that ended meanwhile are missed (none should: the pool lives as long as the service)
            server_cpu = cpu1.get(proc.pid, 0.0) - cpu0.get(proc.pid, 0.0)
            workers_cpu = sum(v - cpu0.get(p, 0.0) for p, v in cpu1.items() if p != proc.pid)
            client_cpu = time.process_time() - client_cpu0
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
    stage_e2e, stage_srv, all_e2e = [], [], []
    outcomes: dict[str, int] = {}
    for _sid, evs in events.items():
        caused = [e for e in evs if e["caused_by"]]
        if not caused:
            continue
        w0 = min(e["caused_by"]["received_at"] - e["caused_by"]["t_device_s"] / args.speed for e in caused)
        for e in caused:
            produced = w0 + e["caused_by"]["t_device_s"] / args.speed
            lat = e["recv"] - produced
            all_e2e.append(lat)
            if e["event"] in STAGE_EVENTS:
                stage_e2e.append(lat)
                stage_srv.append(e["recv"] - e["caused_by"]["received_at"])
        last = evs[-1]
        key = last["state"] + (f" ({last['reason_code']})" if last["reason_code"] else "")
        outcomes[key] = outcomes.get(key, 0) + 1

    def stats(xs: list[float]) -> dict[str, float]:
        a = np.asarray(xs) * 1000.0
        return {"n": int(a.size), "p50_ms": float(np.percentile(a, 50)), "p95_ms": float(np.percentile(a, 95)),
                "p99_ms": float(np.percentile(a, 99)), "max_ms": float(a.max())}

    duration = wall1 - wall0
    return {
        "devices": args.devices,
        "rate_hz": args.rate,
        "speed": args.speed,
        "samples_per_s": args.devices * args.rate * args.speed,
        "duration_s": duration,
        "stage_events_end_to_end": stats(stage_e2e),
        "stage_events_service_side": stats(stage_srv),
        "all_events_end_to_end": stats(all_e2e),
        "server_cpu_percent_of_one_core": 100.0 * server_cpu / duration,
        "workers_cpu_percent_of_one_core": 100.0 * workers_cpu / duration,
        "client_cpu_percent_of_one_core": 100.0 * client_cpu / duration,
        "cores": os.cpu_count(),
        "outcomes": outcomes,
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--devices", type=int, default=20)
    p.add_argument("--rate", type=float, default=562.5, help="sample rate of every wearable, Hz")
    p.add_argument("--speed", type=float, default=1.0, help="simulated time / wall time (1 = real time)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--timeout", type=float, default=300.0)
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    report = asyncio.run(run(args))
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    s, v, a = report["stage_events_end_to_end"], report["stage_events_service_side"], report["all_events_end_to_end"]
    print(f"{report['devices']} simulated wearables at {report['rate_hz']:g} Hz (x{report['speed']:g}): "
          f"{report['samples_per_s']:.0f} samples/s for {report['duration_s']:.1f} s, {report['cores']} cores")
    print(f"stage events, samples -> SSE client: p50 {s['p50_ms']:.1f} ms, p95 {s['p95_ms']:.1f} ms, "
          f"p99 {s['p99_ms']:.1f} ms, max {s['max_ms']:.1f} ms (n={s['n']})")
    print(f"  of which in the service (receive -> client): p50 {v['p50_ms']:.1f} ms, p95 {v['p95_ms']:.1f} ms")
    print(f"all events (incl. live angle/progress): p95 {a['p95_ms']:.1f} ms (n={a['n']})")
    print(f"CPU (% of one core, averaged over the run): service {report['server_cpu_percent_of_one_core']:.0f} %, "
          f"its estimator workers {report['workers_cpu_percent_of_one_core']:.0f} %, "
          f"the benchmark's SSE clients {report['client_cpu_percent_of_one_core']:.0f} %")
    print("outcomes: " + ", ".join(f"{k}: {n}" for k, n in sorted(report["outcomes"].items())))
    return 0


if __name__ == "__main__":
    sys.exit(main())
