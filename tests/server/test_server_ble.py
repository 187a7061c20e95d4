"""`gyrocal serve --ble` with the simulated BlueZ of `gyrocal mock-device --ble`: scan, calibrate, accept."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from server_fixtures import GYROCAL, ROOT, RunningService, follow_events

from wearable_protocol.models import MODELS


def _guided_over_ble(model: str, speed: float, seed: int, store: Path) -> dict[str, Any]:
    """`gyrocal mock-device --ble --model MODEL` and `gyrocal serve --ble` on its bus: scan, calibrate, accept."""
    device = subprocess.Popen([*GYROCAL, "mock-device", "--ble", "--model", model, "--seed", str(seed), "--speed", str(speed)],
                              cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = json.loads(device.stdout.readline())
        svc = RunningService(["--ble", "--ble-time-scale", str(speed), "--log-level", "info"], f"sqlite:///{store}",
                             env={"DBUS_SYSTEM_BUS_ADDRESS": line["dbus_address"]}).start()
        try:
            with svc.client() as c:
                found = c.post("/devices/scan", params={"timeout": 2}).json()["devices"]
                listed = c.get("/devices").json()
                sid = c.post(f"/devices/{line['address']}/calibrate", json={}).json()["session_id"]
            final = follow_events(svc.base, sid, {"done", "failed", "cancelled"}, timeout_s=150, last_event_id=0)[-1]
            with svc.client() as c:
                accepted = c.post(f"/sessions/{sid}/accept").status_code if final["state"] == "done" else None
                cal = c.get(f"/devices/{line['address']}/calibration").json() if accepted == 200 else None
                dev = c.get(f"/devices/{line['address']}").json()
            out = {"line": line, "found": found, "listed": listed, "final": final, "accepted": accepted, "cal": cal, "dev": dev}
        finally:
            svc.stop()
        out["service_log"] = svc.output()[-6000:]  # what the link and the session went through, for a failure's message
    finally:
        device.send_signal(signal.SIGTERM)
        _, device_log = device.communicate(timeout=15)
    out["device_log"] = device_log[-6000:]
    return out


def test_every_model_is_scanned_calibrated_and_stored_through_bleak(tmp_path) -> None:
    """Every wearable model, gyrocal's and the vendors', each on a simulated BlueZ of its own through the service's real
    bleak client: scanned by model, calibrated, accepted. Models that send no time stamps are timed by arrival, so
    their simulated devices run in real time (the service's clock is the wall clock)."""
    if shutil.which("dbus-daemon") is None:
        pytest.fail("dbus-daemon is missing: install the Debian package 'dbus' (make test does it)")
    # the scripted clinicians turn on their script's time, not when asked: at 20x a 3 s pause is 0.15 s of a busy
    # two-core machine, less than the service takes to check a turn there, and the next turn came while it checked.
    # The wearables timed by arrival run in real time, so the test takes their time whatever gyrocal's speed: 20x
    # saved nothing and gave a starved service twice the packets a second of 10x to read
    runs = {"gyrocal": (10.0, 8), "polar-pmd": (5.0, 40), "metawear": (1.0, 41), "thingy52": (1.0, 42),
            "movella-dot": (5.0, 43)}  # (speed, seed)
    with ThreadPoolExecutor(len(runs)) as pool:
        futures = {m: pool.submit(_guided_over_ble, m, speed, seed, tmp_path / f"{m}.sqlite3")
                   for m, (speed, seed) in runs.items()}
        results = {m: f.result() for m, f in futures.items()}
    for model, r in results.items():
        line = r["line"]
        assert line["model"] == model
        assert [(d["id"], d["model"], d["transport"]) for d in r["found"]] == [(line["address"], model, "ble")]
        assert [d["model"] for d in r["listed"]] == [model]
        assert r["final"]["state"] == "done", (model, r["final"]["reason"], r["service_log"], r["device_log"])
        assert r["accepted"] == 200, model
        dev = r["dev"]
        assert dev["model"] == model and dev["connected"] and dev["firmware"] == r["cal"]["firmware"]
        assert dev["sensor_model"] or model != "gyrocal"  # gyrocal's wearable names its sensor; the vendors' do not
        assert dev["sample_rate_hz"] == MODELS[model].stream_rate_hz and dev["gyro_full_scale_dps"] == MODELS[model].gyro_range_dps
        assert dev["limitations"] == list(MODELS[model].limitations())
        np.testing.assert_allclose(r["cal"]["k"], line["simulated_truth"]["k"], atol=3e-3)
        np.testing.assert_allclose(r["cal"]["b"], line["simulated_truth"]["b"], atol=0.03)
