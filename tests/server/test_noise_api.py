"""A rest's noise through the service (POST /noise): the Allan analysis of an upload, its Kalibr file, and every bad
upload named for what it is."""

from __future__ import annotations

from pathlib import Path

import yaml
from server_fixtures import RunningService, native_csv

from calib.simulator import simulate
from calib.simulator.rest_noise import RestNoise, simulate_rest

CSV = {"Content-Type": "text/csv"}


def test_an_uploaded_rest_gives_its_noise_and_kalibrs_file_and_bad_uploads_say_why(tmp_path: Path) -> None:
    rest = simulate_rest(6, 1200.0, 100.0, RestNoise(density=0.01, random_walk=3e-4), RestNoise(density=1e-4))
    svc = RunningService([], f"sqlite:///{tmp_path / 'store.sqlite3'}").start()
    try:
        with svc.client() as c:
            r = c.post("/noise", content=native_csv(rest), headers=CSV, params={"name": "bench-rest.csv", "topic": "/dot/imu"})
            assert r.status_code == 200, r.text
            d = r.json()
            assert d["source"] == "bench-rest.csv" and d["duration_s"] > 1100 and len(d["gyro"]) == len(d["accel"]) == 3
            x = d["gyro"][0]["noise_density"]
            assert x["seen"] and x["ci95"][0] <= 0.01 * 1.02 and x["ci95"][1] >= 0.01 * 0.98
            assert len(d["gyro"][0]["curve"]["tau_s"]) >= 6
            kalibr = yaml.safe_load(d["kalibr_yaml"])
            assert kalibr["rostopic"] == "/dot/imu" and kalibr["update_rate"] == 100
            # nothing stored, and the bad uploads: a recording that turns, too short a rest, not CSV, not signed in
            turned, _ = simulate(2)
            moved = c.post("/noise", content=native_csv(turned), headers=CSV)
            assert moved.status_code == 400 and "turns" in moved.json()["detail"] and "one rest" in moved.json()["detail"]
            short = c.post("/noise", content=native_csv(simulate_rest(1, 2.0, 100.0, RestNoise(density=0.01))), headers=CSV)
            assert short.status_code == 400 and "too short for an Allan analysis" in short.json()["detail"]
            assert c.post("/noise", content=b"{}", headers={"Content-Type": "application/json"}).status_code == 415
            garbage = c.post("/noise", content=b"t,gx\n1,2\n", headers=CSV)
            assert garbage.status_code == 400, garbage.text
            assert c.post("/noise", content=native_csv(rest), headers=CSV, params={"topic": "no slash"}).status_code == 422
        with svc.client(token=None) as anon:
            assert anon.post("/noise", content=native_csv(rest), headers=CSV).status_code == 401
    finally:
        svc.stop()
