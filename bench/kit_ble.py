"""A kit of simulated wearables of mixed models calibrated in one guided session through the service's real bleak
client, on the simulated BlueZ (one adapter): `gyrocal mock-device --ble --kit MODELS` and `gyrocal serve --ble` on
its private D-Bus; scan, POST /kits/calibrate, follow it to its end, accept every one that passed.

Run: .venv/bin/python bench/kit_ble.py [--models gyrocal,polar-pmd,metawear,thingy52,gyrocal] [--seed 5] [--json out.json]

The models that send no time stamps are timed by their packets' arrival, so the wearables run in real time. Reported:
the kit's end state and time, each wearable's model, state, samples, lost samples, k against the simulated truth, and
the calibrations stored.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
from local_service import free_port, scratch_dir, wait_until_up

ROOT = Path(__file__).resolve().parents[1]
GYROCAL = [sys.executable, "-m", "calib.cli.main"]
TOKEN = "bench-kit-ble"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--models", default="gyrocal,polar-pmd,metawear,thingy52,gyrocal")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    device = subprocess.Popen([*GYROCAL, "mock-device", "--ble", "--kit", args.models, "--seed", str(args.seed)],
                              cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    tmp = scratch_dir("gyrocal-kit-ble-")
    port = free_port()
    try:
        line = json.loads(device.stdout.readline())
        env = {**os.environ, "DBUS_SYSTEM_BUS_ADDRESS": line["dbus_address"], "GYROCAL_API_TOKEN": TOKEN}
        svc = subprocess.Popen([*GYROCAL, "serve", "--ble", "--port", str(port), "--db", f"sqlite:///{tmp / 'store.sqlite3'}",
                                "--log-level", "warning"], cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
        try:
            c = httpx.Client(base_url=f"http://127.0.0.1:{port}", headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60)
            wait_until_up(c)
            found = c.post("/devices/scan", params={"timeout": 3}).json()["devices"]
            truth = {d["address"]: d for d in line["devices"]}
            ids = [d["address"] for d in line["devices"]]
            assert sorted(d["id"] for d in found) == sorted(ids), found
            t0 = time.monotonic()
            started = c.post("/kits/calibrate", json={"devices": ids})
            assert started.status_code == 202, started.text
            kit_id = started.json()["session_id"]
            while True:
                snap = c.get(f"/sessions/{kit_id}").json()
                if snap["state"] in ("done", "failed", "cancelled"):
                    break
                time.sleep(0.5)
            elapsed = time.monotonic() - t0
            accepted = c.post(f"/kits/{kit_id}/accept")
            rows = []
            for d in snap["devices"]:
                t = truth[d["device_id"]]
                k = d["result"]["k"] if d["result"] else None
                rows.append({"device": d["device_id"], "model": t["model"], "state": d["state"], "passed": d["passed"],
                             "samples": d["samples"], "lost_samples": d["lost_samples"], "reason": d["reason"],
                             "k_error": None if k is None else (np.array(k) - np.array(t["simulated_truth"]["k"])).tolist(),
                             "k_std": None if k is None else d["result"]["uncertainty"]["k"]})
            out = {"state": snap["state"], "seconds": elapsed, "devices": rows, "accept_status": accepted.status_code,
                   "stored": [r["device_id"] for r in accepted.json().get("calibrations", [])] if accepted.status_code == 200 else []}
            print(f"kit of {len(ids)} over BLE: {snap['state']} in {elapsed:.1f} s; stored {len(out['stored'])} calibrations")
            for r in rows:
                err = "-" if r["k_error"] is None else " ".join(f"{v:+.1e}" for v in r["k_error"])
                print(f"  {r['model']:10} {r['state']:7} samples {r['samples']:5} lost {r['lost_samples']:3}  k - truth {err}")
            if args.json:
                Path(args.json).write_text(json.dumps(out, indent=1))
        finally:
            svc.send_signal(signal.SIGINT)
            svc.wait(timeout=20)
    finally:
        device.send_signal(signal.SIGTERM)
        device.communicate(timeout=15)


if __name__ == "__main__":
    main()
