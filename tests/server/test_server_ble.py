"""`gyrocal serve --ble` with the simulated BlueZ of `gyrocal mock-device --ble`: scan, calibrate, accept."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess

import numpy as np
import pytest
from server_fixtures import GYROCAL, ROOT, RunningService, follow_events


def test_ble_wearable_is_scanned_calibrated_and_stored(tmp_path) -> None:
    if shutil.which("dbus-daemon") is None:
        pytest.fail("dbus-daemon is missing: install the Debian package 'dbus' (make test does it)")
    device = subprocess.Popen([*GYROCAL, "mock-device", "--ble", "--seed", "8", "--speed", "20"], cwd=ROOT,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = json.loads(device.stdout.readline())
        svc = RunningService(["--ble"], f"sqlite:///{tmp_path / 'store.sqlite3'}",
                             env={"DBUS_SYSTEM_BUS_ADDRESS": line["dbus_address"]}).start()
        try:
            with svc.client() as c:
                found = c.post("/devices/scan", params={"timeout": 2}).json()["devices"]
                assert [(d["id"], d["transport"]) for d in found] == [(line["address"], "ble")]
                r = c.post(f"/devices/{line['address']}/calibrate", json={})
                assert r.status_code == 202, r.text
                sid = r.json()["session_id"]
            events = follow_events(svc.base, sid, {"done", "failed", "cancelled"}, timeout_s=120, last_event_id=0)
            final = events[-1]
            assert final["state"] == "done", final["reason"]
            with svc.client() as c:
                assert c.post(f"/sessions/{sid}/accept").status_code == 200
                cal = c.get(f"/devices/{line['address']}/calibration").json()
                dev = c.get(f"/devices/{line['address']}").json()
            assert dev["connected"] and dev["sensor_model"] and dev["firmware"] == cal["firmware"]
            np.testing.assert_allclose(cal["k"], line["simulated_truth"]["k"], atol=3e-3)
            np.testing.assert_allclose(cal["b"], line["simulated_truth"]["b"], atol=0.03)
        finally:
            svc.stop()
    finally:
        device.send_signal(signal.SIGTERM)
        device.communicate(timeout=15)
