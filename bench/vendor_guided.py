"""Guided calibrations of every wearable model through the service's bleak client on the simulated BlueZ.

For each model, ``gyrocal mock-device --ble --model M --count N`` serves N simulated wearables (distinct
sensors and clinicians) and ``gyrocal serve --ble`` on that bus scans them and runs a guided calibration on
each, all at once. Models that send no time stamps (MetaWear, Thingy:52) are timed by arrival, so their
devices run in real time; the others run --speed times faster. The models run one after the other
(--parallel: side by side, which loads the machine enough to starve the faster-than-real-time devices).

Reported per model: sessions that passed, |dk| and |db| against the simulated truth (median, 95th
percentile, max), and the errors over the estimator's own standard errors (z = dk / k_std): z of about 1
means the estimator is at its bound for that device's rate and noise, whatever the protocol.

Run: .venv/bin/python bench/vendor_guided.py [--devices 5] [--rounds 2] [--speed 20] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
GYROCAL = [sys.executable, "-m", "calib.cli.main"]
TOKEN = "bench-" + uuid.uuid4().hex
MODELS = ("gyrocal", "polar-pmd", "metawear", "thingy52", "movella-dot")
ARRIVAL_TIMED = {"metawear", "thingy52"}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_done(base: str, sid: str, timeout_s: float) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    with httpx.Client(base_url=base, timeout=10) as c:
        while time.monotonic() < deadline:
            snap = c.get(f"/sessions/{sid}").json()
            if snap["state"] in ("done", "failed", "cancelled"):
                return snap
            time.sleep(0.5)
    raise TimeoutError(f"session {sid} did not end within {timeout_s} s")


def run_model(model: str, devices: int, rounds: int, speed: float, seed: int) -> list[dict[str, Any]]:
    """Guided sessions on ``devices`` simulated wearables of ``model``, ``rounds`` times each."""
    speed = 1.0 if model in ARRIVAL_TIMED else speed
    out: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix=f"gyrocal-bench-{model}-") as tmp:
        dev = subprocess.Popen([*GYROCAL, "mock-device", "--ble", "--model", model, "--count", str(devices), "--seed", str(seed),
                                "--speed", str(speed)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        assert dev.stdout is not None
        line = json.loads(dev.stdout.readline())
        truths = {d["address"]: d["simulated_truth"] for d in line.get("devices", [line])}
        port = _free_port()
        env = {**os.environ, "DBUS_SYSTEM_BUS_ADDRESS": line["dbus_address"], "GYROCAL_API_TOKEN": TOKEN}
        svc = subprocess.Popen([*GYROCAL, "serve", "--ble", "--ble-time-scale", str(speed), "--port", str(port), "--db",
                                f"sqlite:///{tmp}/store.sqlite3", "--log-level", "warning"], cwd=ROOT, env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        base = f"http://127.0.0.1:{port}"
        try:
            with httpx.Client(base_url=base, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30) as c:
                for _ in range(300):
                    try:
                        if c.get("/health").status_code == 200:
                            break
                    except httpx.HTTPError:
                        time.sleep(0.1)
                found = c.post("/devices/scan", params={"timeout": 3}).json()["devices"]
                ids = [d["id"] for d in found if d["model"] == model]
                for _ in range(rounds):
                    sids = {i: c.post(f"/devices/{i}/calibrate", json={}).json()["session_id"] for i in ids}
                    with ThreadPoolExecutor(len(sids)) as pool:
                        snaps = dict(zip(sids, pool.map(lambda s: _wait_done(base, s, 300), sids.values()), strict=True))
                    for address, snap in snaps.items():
                        out.append({"model": model, "address": address, "snapshot": snap, "truth": truths[address]})
                        if snap["state"] == "done":
                            c.post(f"/sessions/{snap['session_id']}/discard")
        finally:
            svc.send_signal(signal.SIGINT)
            svc.wait(timeout=30)
            dev.send_signal(signal.SIGTERM)
            dev.wait(timeout=30)
    return out


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    done = [r for r in runs if r["snapshot"]["state"] == "done" and r["snapshot"].get("result")]
    if not done:
        return {"sessions": len(runs), "passed": 0}
    res = [r["snapshot"]["result"] for r in done]
    dk = np.array([np.abs(np.subtract(x["k"], r["truth"]["k"])) for x, r in zip(res, done, strict=True)])
    db = np.array([np.abs(np.subtract(x["b"], r["truth"]["b"])) for x, r in zip(res, done, strict=True)])
    zk = np.array([d / np.asarray(x["uncertainty"]["k"]) for d, x in zip(dk, res, strict=True) if x.get("uncertainty")])
    zb = np.array([d / np.asarray(x["uncertainty"]["b"]) for d, x in zip(db, res, strict=True) if x.get("uncertainty")])
    bound_k = np.array([np.asarray(x["bound"]["k"]) for x in res if x.get("bound")])

    def q(a: np.ndarray) -> dict[str, float]:
        return {"median": float(np.median(a)), "p95": float(np.percentile(a, 95)), "max": float(np.max(a))}

    reasons: dict[str, int] = {}
    for r in runs:
        if not r["snapshot"].get("passed"):
            code = r["snapshot"].get("reason_code") or "out_of_tolerance"
            reasons[code] = reasons.get(code, 0) + 1
    return {"sessions": len(runs), "passed": sum(1 for r in done if r["snapshot"].get("passed")), "not_passed": reasons,
            "dk": q(dk), "db": q(db), "k_bound_median": float(np.median(bound_k)) if bound_k.size else None,
            "z_k_rms": float(np.sqrt(np.mean(zk**2))) if zk.size else None,
            "z_b_rms": float(np.sqrt(np.mean(zb**2))) if zb.size else None}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--devices", type=int, default=5,
                    help="simulated wearables per model (default 5: the connection slots of the one simulated adapter)")
    ap.add_argument("--rounds", type=int, default=2, help="guided sessions per wearable (default 2)")
    ap.add_argument("--speed", type=float, default=20.0, help="time scale of the device-timed models (default 20)")
    ap.add_argument("--models", default=",".join(MODELS))
    ap.add_argument("--parallel", action="store_true", help="run the models side by side")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    models = [m.strip() for m in args.models.split(",") if m.strip()]
    t0 = time.monotonic()
    with ThreadPoolExecutor(len(models) if args.parallel else 1) as pool:
        runs = dict(zip(models, pool.map(lambda m: run_model(m, args.devices, args.rounds, args.speed, 100 + 10 * models.index(m)),
                                         models), strict=True))
    summary = {m: summarise(r) for m, r in runs.items()}
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    print(f"{args.devices} wearables x {args.rounds} rounds per model, {time.monotonic() - t0:.0f} s")
    print(f"{'model':11s} {'passed':>8s} {'|dk| median':>12s} {'p95':>9s} {'max':>9s} {'k bound':>9s} {'|db| median':>12s}"
          f" {'p95':>8s} {'max':>8s} {'z_k rms':>8s} {'z_b rms':>8s}  not passed")
    for m, s in summary.items():
        if "dk" not in s:
            print(f"{m:11s} {s['passed']:>3d}/{s['sessions']:<4d} (no result)")
            continue
        print(f"{m:11s} {s['passed']:>3d}/{s['sessions']:<4d} {s['dk']['median']:12.1e} {s['dk']['p95']:9.1e} {s['dk']['max']:9.1e}"
              f" {s['k_bound_median'] or float('nan'):9.1e} {s['db']['median']:12.4f} {s['db']['p95']:8.4f} {s['db']['max']:8.4f}"
              f" {s['z_k_rms'] or float('nan'):8.2f} {s['z_b_rms'] or float('nan'):8.2f}  {s['not_passed'] or ''}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
