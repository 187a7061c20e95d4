"""A study recording watched against the calibration in force, through the service (POST /calibrations/{id}/watch):
the verdict kept with the calibration, listed, and read by the device's "due": a calibration a study recording showed
moved is due now, with the reason, on the device, the fleet page and `gyrocal history`; one it showed holding says so."""

from __future__ import annotations

import json
import subprocess
from dataclasses import replace
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
from server_fixtures import GYROCAL, ROOT, RunningService, native_csv

from calib.apply.correction import Correction
from calib.io.readers import read_recording
from calib.simulator import SensorParams, simulate
from calib.simulator.study_day import StudyEvent, simulate_study_day
from calib.watch import watch
from server.lifecycle import calibration_due
from server.store import StoredWatch

CSV = {"Content-Type": "text/csv"}


def test_a_study_recording_is_watched_kept_and_a_moved_calibration_is_due_now(tmp_path: Path) -> None:
    quiet, day = simulate_study_day(4, 1200.0)
    dropped, _ = simulate_study_day(4, 1200.0, event=StudyEvent(800.0, "b", 2, 0.3))  # the same day, dropped at 800 s
    db = f"sqlite:///{tmp_path / 'store.sqlite3'}"
    svc = RunningService([], db).start()
    try:
        with svc.client() as c:
            cal = {"k": day.params.k.tolist(), "b": day.params.b.tolist(), "identity": {"temperature_c": day.temp_cal_c}}
            r = c.post("/devices/ward-1/calibrations", content=json.dumps(cal), headers={"Content-Type": "application/json"})
            assert r.status_code == 201, r.text
            cid = r.json()["calibration"]["id"]
            # a quiet day: every parameter holds, and the device says a study recording showed it
            held = c.post(f"/calibrations/{cid}/watch", content=native_csv(quiet), headers=CSV, params={"name": "day-1.csv"})
            assert held.status_code == 201, held.text
            w = held.json()
            assert w["verdict"] == "holds" and w["recording"] == "day-1.csv" and w["calibration_id"] == cid, w
            assert {p["name"] for p in w["parameters"]} == {"k_x", "k_y", "k_z", "b_x", "b_y", "b_z"}
            assert w["temperature_c"][1] - w["temperature_c"][0] > 5 and w["bias"]["temperature_coeff_dps_per_c"] is not None
            due = c.get("/devices/ward-1").json()["calibration_due"]
            assert due["due"] is False and "a study recording showed it holds" in due["reason"], due
            # the report is typed in the OpenAPI document
            spec = c.get("/openapi.json").json()
            answer = spec["paths"]["/calibrations/{calibration_id}/watch"]["post"]["responses"]["201"]["content"]["application/json"]
            assert answer["schema"]["$ref"].endswith("/StoredWatch")
            assert "ParameterOut" in spec["components"]["schemas"] and "TemperatureModelOut" in spec["components"]["schemas"]
            model = c.get("/devices/ward-1/temperature-model").json()
            assert model["watches"] == 1 and model["temp_ref_c"] == day.temp_cal_c
            assert np.all(np.abs(np.array(model["bias_tc_dps_per_c"]) - day.bias_tc) <= 0.2 * np.abs(day.bias_tc)), model
            # what the watch measured of the bias against temperature corrects the device's recordings, sample by sample
            fixed = c.post("/devices/ward-1/apply", content=native_csv(quiet), headers=CSV)
            assert fixed.status_code == 200, fixed.text
            model = json.loads(fixed.headers["x-gyrocal-temperature-model"])
            assert model["applied"] == "per sample" and model["watches"] == 1, model
            (tmp_path / "fixed.csv").write_text(fixed.text)
            alone = quiet.gyro * day.params.k + day.params.b
            assert day.rate is not None
            error = [np.mean(np.abs(g - day.rate)) for g in (read_recording(tmp_path / "fixed.csv").gyro, alone)]
            assert error[0] < 0.5 * error[1], error
            # the day it was dropped: b_z moved, when, and the device is due now, saying why
            moved = c.post(f"/calibrations/{cid}/watch", content=native_csv(dropped), headers=CSV, params={"name": "day-2.csv"})
            assert moved.status_code == 201, moved.text
            m = moved.json()
            said = {p["name"]: p for p in m["parameters"] if p["verdict"] == "moved"}
            assert m["verdict"] == "moved" and list(said) == ["b_z"], m["parameters"]
            assert abs(said["b_z"]["change"] - 0.3) < 0.05 and said["b_z"]["since"]["after_s"] <= 800 <= said["b_z"]["since"]["before_s"]
            due = c.get("/devices/ward-1").json()["calibration_due"]
            assert due["due"] is True and "a study recording watched today showed b_z moved by +0.3" in due["reason"], due
            listed = c.get("/devices/ward-1/watches").json()
            assert [x["recording"] for x in listed] == ["day-2.csv", "day-1.csv"]
            assert c.get(f"/calibrations/{cid}/watches").json() == listed
            fleet = {d["id"]: d for d in c.get("/fleet").json()["devices"]}
            assert fleet["ward-1"]["calibration"]["status"] == "due" and "b_z moved" in fleet["ward-1"]["calibration"]["reason"]
            # a watch asks no decision: the device list does not take it for an unsaved result; the sessions list it
            assert c.get("/devices/ward-1").json()["unsaved_session"] is None
            kept = c.get("/devices/ward-1/sessions").json()
            assert [s["kind"] for s in kept[:2]] == ["watch", "watch"] and kept[0]["result"]["verdict"] == "moved", kept[:2]
            assert c.get(f"/sessions/{m['session_id']}").json()["passed"] is False
            # bad input is named, and nothing is kept of it
            for body, ctype, status, words in (
                ("k,b", "application/json", 415, "text/csv"),
                ("t,gx,gy,gz\n0,0,0,0\n", "text/csv", 400, None),
            ):
                bad = c.post(f"/calibrations/{cid}/watch", content=body, headers={"Content-Type": ctype})
                assert bad.status_code == status, (body, bad.text)
                assert words is None or words in bad.json()["detail"], bad.text
            spinning = np.column_stack([np.arange(3000) / 100.0, 60 * np.sin(np.arange(3000) / 100.0),
                                        40 * np.cos(np.arange(3000) / 77.0), 20 * np.sin(np.arange(3000) / 50.0)])
            body = "t,gx,gy,gz\n" + "\n".join(",".join(f"{v:.4f}" for v in row) for row in spinning) + "\n"
            bad = c.post(f"/calibrations/{cid}/watch", content=body, headers=CSV)
            assert bad.status_code == 422 and "lies still now and then" in bad.json()["detail"], bad.text
            assert c.post("/calibrations/999/watch", content=native_csv(quiet), headers=CSV).status_code == 404
            assert len(c.get("/devices/ward-1/watches").json()) == 2
        with svc.client(token=None) as anonymous:
            assert anonymous.post(f"/calibrations/{cid}/watch", content=native_csv(quiet), headers=CSV).status_code == 401
        history = subprocess.run([*GYROCAL, "history", "ward-1", "--db", db, "--json"], cwd=ROOT, capture_output=True, text=True,
                                 timeout=120)
        assert history.returncode == 0, history.stderr
        assert json.loads(history.stdout)["calibration_due"]["due"] is True
        (tmp_path / "day-3.csv").write_text(native_csv(quiet))
        applied = subprocess.run([*GYROCAL, "apply", str(tmp_path / "day-3.csv"), "--device", "ward-1", "--db", db], cwd=ROOT,
                                 capture_output=True, text=True, timeout=120)
        assert applied.returncode == 0 and "against temperature (2 watched recording(s)) applied per sample" in applied.stdout, (
            applied.stdout + applied.stderr)
        side = json.loads((tmp_path / "day-3.calibrated.calibration.json").read_text())
        assert side["temperature_model"]["applied"] == "per sample" and side["temperature_model"]["watches"] == 2
        # and the command line watches a recording against the device's calibration in force, from the store
        watched = subprocess.run([*GYROCAL, "watch", str(tmp_path / "day-3.csv"), "--device", "ward-1", "--db", db, "--json"],
                                 cwd=ROOT, capture_output=True, text=True, timeout=120)
        assert watched.returncode == 0, watched.stdout[-2000:] + watched.stderr
        said = json.loads(watched.stdout)
        assert said["verdict"] == "holds" and said["calibration"]["calibration_id"] == cid, said["calibration"]
    finally:
        svc.stop()


def _stored(report: dict, days_ago: float, now: datetime) -> StoredWatch:
    at = (now - timedelta(days=days_ago)).isoformat()
    return StoredWatch.model_validate({**report, "session_id": "0" * 32, "calibration_id": 1, "device_id": "ward-1", "at": at,
                                       "operator": "alice"})


def test_a_calibration_a_study_recording_confirmed_is_not_due_by_age_alone() -> None:
    rec, day = simulate_study_day(3, 900.0)
    report = watch(rec, Correction(K=np.diag(day.params.k), b=day.params.b.copy()), temp_cal_c=day.temp_cal_c).to_json()
    assert report["verdict"] == "holds"
    now = datetime(2026, 12, 7, tzinfo=UTC)
    accepted = now - timedelta(days=40)
    assert calibration_due(accepted, 30, now).due  # old, and nothing says it holds
    fresh = calibration_due(accepted, 30, now, latest_watch=_stored(report, 3, now))
    assert not fresh.due and "a study recording watched 3 days ago showed it holds" in fresh.reason, fresh
    stale = calibration_due(accepted, 30, now, latest_watch=_stored(report, 35, now))
    assert stale.due and "more than the 30 days allowed" in stale.reason, stale
    moved = {**report, "verdict": "moved", "parameters": [{**p, "verdict": "moved", "change": 0.012, "std": 0.0003}
                                                          if p["name"] == "k_x" else p for p in report["parameters"]]}
    young = calibration_due(now - timedelta(days=2), 30, now, latest_watch=_stored(moved, 1, now))
    assert young.due and young.reason == "a study recording watched 1 day ago showed k_x moved by +1.20 % ± 0.03 %", young


def test_calibrations_of_one_power_up_at_two_temperatures_give_the_device_its_model(tmp_path: Path) -> None:
    """Two calibrations of power-up #4 made 10 degC apart (and one of another power-up, far off, which must not be
    put on their line): the device's model is their slope, and apply corrects at the temperature it is given."""
    params = SensorParams(np.array([1.05, 0.95, 1.02]), np.array([1.0, -2.0, 0.5]))
    c, s = np.array([0.03, -0.02, 0.01]), np.array([2e-4, -1e-4, 1e-4])

    def at(T: float) -> SensorParams:
        return SensorParams(params.k * (1 + s * (T - 22.0)), params.b + c * (T - 22.0))

    svc = RunningService([], f"sqlite:///{tmp_path / 'store.sqlite3'}").start()
    try:
        with svc.client() as cl:
            for seed, T, boot in ((31, 32.0, 4), (32, 25.0, 3), (33, 22.0, 4)):  # the last accepted is the current one
                rec, _ = simulate(seed, noise=0.03, params=at(T) if boot == 4 else SensorParams(params.k * 1.01, params.b + 0.4))
                rec = replace(rec, temp=np.full(len(rec), T))  # its temperature column: the calibration's temperature
                r = cl.post("/devices/thigh-2/calibrate", content=native_csv(rec), headers=CSV,
                            params={"sensor_model": "ICM-20948", "firmware": "1.2.0", "boot_count": boot})
                assert r.status_code == 200 and r.json()["passed"], r.text
                ok = cl.post(f"/sessions/{r.json()['session_id']}/accept")
                assert ok.status_code == 200, ok.text
            model = cl.get("/devices/thigh-2/temperature-model").json()
            assert model["calibrations"] == 2 and model["watches"] == 0 and model["temp_ref_c"] == 22.0, model
            assert np.allclose(model["bias_tc_dps_per_c"], c, atol=3e-3), model
            assert model["watched_c"] == [22.0, 32.0]
            rec, _ = simulate(34, noise=0.03, params=at(30.0))
            fixed = cl.post("/devices/thigh-2/apply", content=native_csv(rec), headers=CSV, params={"temperature_c": 30.0})
            assert fixed.status_code == 200, fixed.text
            assert json.loads(fixed.headers["x-gyrocal-temperature-model"])["applied"] == "at 30 °C"
    finally:
        svc.stop()
