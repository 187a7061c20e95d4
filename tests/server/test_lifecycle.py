"""The calibration in force at a moment: the latest accepted at or before it, with its age and a warning past the
age limit; 404 (exit 5) before the first; the same answer from the REST API and the CLI. Applying it: a recording
corrected by the device's calibration in force (CLI and REST give the same bytes) or by a calibration file."""

from __future__ import annotations

import io
import json
import subprocess
import time
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from server_fixtures import GYROCAL, ROOT, RunningService, follow_events

from calib.apply.correction import Correction
from calib.io.readers import read_recording, write_native_csv
from calib.simulator import simulate

DEVICE = "ward-3-unit-12"


@pytest.fixture(scope="module")
def history(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[RunningService, list[dict[str, Any]]]]:
    """A service whose store holds three accepted calibrations of DEVICE, a moment apart."""
    db = f"sqlite:///{tmp_path_factory.mktemp('lifecycle') / 'store.sqlite3'}"
    svc = RunningService([], db).start()
    cals = []
    try:
        with svc.client() as c:
            for seed in (1, 2, 3):
                rec, _ = simulate(seed, noise=0.03)
                buf = io.StringIO()
                write_native_csv(rec, buf)
                r = c.post(f"/devices/{DEVICE}/calibrate", content=buf.getvalue(), headers={"Content-Type": "text/csv"},
                           params={"sensor_model": "ICM-20948", "firmware": "1.2.0"})
                assert r.status_code == 200 and r.json()["passed"], r.text
                r = c.post(f"/sessions/{r.json()['session_id']}/accept")
                assert r.status_code == 200, r.text
                cals.append(r.json()["calibration"])
                time.sleep(0.05)
        yield svc, cals
    finally:
        svc.stop()


def _t(iso: str) -> datetime:
    return datetime.fromisoformat(iso)


def _between(a: dict[str, Any], b: dict[str, Any]) -> datetime:
    ta, tb = _t(a["accepted_at"]), _t(b["accepted_at"])
    return ta + (tb - ta) / 2


def test_the_calibration_in_force_is_the_latest_accepted_by_then(history: tuple[RunningService, list[dict[str, Any]]]) -> None:
    svc, cals = history
    with svc.client() as c:
        now = c.get(f"/devices/{DEVICE}/calibration").json()
        assert now["id"] == cals[-1]["id"] and now["in_force"]["warnings"] == [] and now["in_force"]["age_days"] >= 0
        for i, (a, b) in enumerate(zip(cals, cals[1:], strict=False)):
            got = c.get(f"/devices/{DEVICE}/calibration", params={"at": _between(a, b).isoformat()}).json()
            assert got["id"] == cals[i]["id"], (i, got["id"])
        # the moment of an acceptance is in force of that calibration
        assert c.get(f"/devices/{DEVICE}/calibration", params={"at": cals[1]["accepted_at"]}).json()["id"] == cals[1]["id"]
        # the same moment written in another time zone is the same moment
        local = _between(cals[0], cals[1]).astimezone(timezone(timedelta(hours=5, minutes=30))).isoformat()
        assert c.get(f"/devices/{DEVICE}/calibration", params={"at": local}).json()["id"] == cals[0]["id"]


def test_an_old_calibration_is_warned_of_and_none_before_the_first(history: tuple[RunningService, list[dict[str, Any]]]) -> None:
    svc, cals = history
    later = _t(cals[-1]["accepted_at"]) + timedelta(days=45)
    with svc.client() as c:
        got = c.get(f"/devices/{DEVICE}/calibration", params={"at": later.isoformat()}).json()
        assert got["id"] == cals[-1]["id"] and round(got["in_force"]["age_days"]) == 45
        assert len(got["in_force"]["warnings"]) == 1 and "45 days" in got["in_force"]["warnings"][0]
        before = _t(cals[0]["accepted_at"]) - timedelta(seconds=1)
        r = c.get(f"/devices/{DEVICE}/calibration", params={"at": before.isoformat()})
        assert r.status_code == 404 and "no accepted calibration by" in r.json()["detail"]
        r = c.get(f"/devices/{DEVICE}/calibration", params={"at": "last tuesday"})
        assert r.status_code == 422


def _cli(svc: RunningService, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*GYROCAL, "calibration", DEVICE, "--db", svc.db_url, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=60)


def test_the_cli_gives_the_same_answer(history: tuple[RunningService, list[dict[str, Any]]]) -> None:
    svc, cals = history
    r = _cli(svc, "--at", _between(cals[1], cals[2]).isoformat())
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["id"] == cals[1]["id"]
    r = _cli(svc, "--at", (_t(cals[-1]["accepted_at"]) + timedelta(days=3)).isoformat(), "--max-age-days", "2")
    assert r.returncode == 0 and "more than the 2 days allowed" in json.loads(r.stdout)["in_force"]["warnings"][0]
    r = _cli(svc, "--at", "2001-01-01T00:00")
    assert r.returncode == 5 and "no accepted calibration by 2001-01-01T00:00" in r.stdout
    r = _cli(svc, "--at", "yesterday")
    assert r.returncode != 0 and "not an ISO 8601 time" in r.stderr and "Traceback" not in r.stderr


def _recording_csv(tmp: Path, seed: int = 9) -> tuple[Path, Any]:
    rec, truth = simulate(seed, noise=0.03)
    path = tmp / "study.csv"
    write_native_csv(rec, path)
    return path, rec


def test_apply_corrects_a_recording_with_the_devices_calibration_in_force(
    history: tuple[RunningService, list[dict[str, Any]]], tmp_path: Path
) -> None:
    svc, cals = history
    src, rec = _recording_csv(tmp_path)
    out = tmp_path / "study-corrected.csv"
    at = _between(cals[0], cals[1]).isoformat()
    r = subprocess.run([*GYROCAL, "apply", str(src), "--device", DEVICE, "--at", at, "--db", svc.db_url, "-o", str(out)], cwd=ROOT,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    got = read_recording(out)
    want = rec.gyro @ np.diag(cals[0]["k"]).T + np.asarray(cals[0]["b"])
    assert np.allclose(got.gyro, want, atol=1e-9) and np.array_equal(got.t, rec.t)
    side = json.loads(out.with_suffix(".calibration.json").read_text())
    assert side["calibration_id"] == cals[0]["id"] and side["calibration"]["k"] == pytest.approx(cals[0]["k"])
    # the same over HTTP, at the same moment
    with svc.client() as c:
        resp = c.post(f"/devices/{DEVICE}/apply", content=src.read_text(), params={"at": at}, headers={"Content-Type": "text/csv"})
        assert resp.status_code == 200, resp.text
        assert resp.headers["content-type"].startswith("text/csv") and resp.headers["x-gyrocal-calibration-id"] == str(cals[0]["id"])
        assert json.loads(resp.headers["x-gyrocal-warnings"]) == []
        assert resp.text == out.read_text()
        # the orientation before and after, for the page's plots
        o = c.post(f"/devices/{DEVICE}/orientation", content=src.read_text(), params={"at": at}, headers={"Content-Type": "text/csv"})
        assert o.status_code == 200, o.text
        o = o.json()
        assert o["calibration_id"] == cals[0]["id"] and "Madgwick" in o["method"] and len(o["t"]) == len(o["before"]["yaw"]) <= 2000
        assert o["final_difference_deg"] > 1.0 and o["difference_deg"][0] == 0.0
        # a device with no calibration, a body that is no CSV: said, nothing else
        r404 = c.post("/devices/never-calibrated/apply", content=src.read_text(), headers={"Content-Type": "text/csv"})
        assert r404.status_code == 404 and "calibrate it before" in r404.json()["detail"]
        assert c.post(f"/devices/{DEVICE}/apply", json={"k": [1, 1, 1]}).status_code == 415
        bad = c.post(f"/devices/{DEVICE}/apply", content="not,a,recording\n1,2,3\n", headers={"Content-Type": "text/csv"})
        assert bad.status_code == 400


def test_apply_with_a_calibration_file_gyrocals_or_imucals(tmp_path: Path) -> None:
    src, rec = _recording_csv(tmp_path, seed=10)
    corr = Correction(K=np.diag([1.1, 0.95, 1.02]), b=np.array([0.3, -0.4, 0.5]))
    for name, doc in (("ours.json", corr.to_json()), ("imucal.json", corr.to_imucal())):
        cal = tmp_path / name
        cal.write_text(json.dumps(doc))
        out = tmp_path / f"out-{name}.csv"
        r = subprocess.run([*GYROCAL, "apply", str(src), "--calibration", str(cal), "-o", str(out)], cwd=ROOT, capture_output=True,
                           text=True, timeout=60)
        assert r.returncode == 0, r.stderr
        assert np.allclose(read_recording(out).gyro, corr.apply(rec.gyro)[0], atol=1e-9), name
    # with the orientation before and after: a table, a plot and the sidecar's summary
    out = tmp_path / "oriented.csv"
    r = subprocess.run([*GYROCAL, "apply", str(src), "--calibration", str(tmp_path / "ours.json"), "-o", str(out), "--orientation"],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "oriented.orientation.png" in r.stdout, r.stdout + r.stderr
    side = json.loads((tmp_path / "oriented.calibration.json").read_text())["orientation"]
    table = np.genfromtxt(tmp_path / "oriented.orientation.csv", delimiter=",", names=True)
    assert len(table) == len(rec) and side["final_difference_deg"] == pytest.approx(table["difference"][-1], abs=1e-4)
    assert "Madgwick" in side["method"] and (tmp_path / "oriented.orientation.png").read_bytes()[:4] == b"\x89PNG"
    broken = tmp_path / "broken.json"
    broken.write_text('{"k": [1, 1]}')
    r = subprocess.run([*GYROCAL, "apply", str(src), "--calibration", str(broken)], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and "three finite numbers" in r.stderr and "Traceback" not in r.stderr


def test_export_for_imucal_is_loaded_by_the_real_imucal_and_gives_back_our_numbers(
    history: tuple[RunningService, list[dict[str, Any]]], tmp_path: Path
) -> None:
    from imucal.management import load_calibration_info

    svc, cals = history
    cal = cals[1]
    with svc.client() as c:
        r = c.get(f"/calibrations/{cal['id']}", params={"format": "imucal"})
        assert r.status_code == 200 and "attachment" in r.headers["content-disposition"]
        path = tmp_path / "from-api.json"
        path.write_bytes(r.content)
        as_csv = c.get(f"/calibrations/{cal['id']}", params={"format": "csv"}).text
        assert c.get(f"/calibrations/{cal['id']}").json()["k"] == cal["k"]
        assert c.get("/calibrations/999999").status_code == 404
        assert c.get(f"/calibrations/{cal['id']}", params={"format": "xls"}).status_code == 422
        ov = c.get(f"/calibrations/{cal['id']}", params={"format": "openvins"})
        assert ov.status_code == 200 and ov.text.startswith("%YAML:1.0") and ".kalibr_imu_chain.yaml" in ov.headers["content-disposition"]
    from robotics_readers import openvins_correct, read_openvins

    ovc = read_openvins(ov.text)
    m, r_acc = np.random.default_rng(3).normal(0, 50, (20, 3)), np.tile([0.0, 0.0, 1.0], (20, 1))
    w, _ = openvins_correct(ovc, np.radians(m), r_acc * 9.80665)
    assert np.allclose(np.degrees(w), Correction.from_json(cal).apply(m, r_acc)[0], atol=1e-6)
    info = load_calibration_info(path)
    # imucal's convention: K_g = diag(1/k), b_g = -b/k, no rotation, no g-sensitivity (none was fitted)
    assert np.allclose(np.diag(info.K_g), 1.0 / np.asarray(cal["k"]), rtol=1e-12)
    assert np.allclose(info.b_g, -np.asarray(cal["b"]) / np.asarray(cal["k"]), rtol=1e-12)
    assert np.allclose(info.R_g, np.eye(3)) and not np.any(info.K_ga)
    gyro = np.random.default_rng(8).normal(0, 100, (20, 3))
    _, gyr = info.calibrate(np.zeros((20, 3)), gyro, acc_unit="g", gyr_unit="deg/s")
    assert np.allclose(gyr, gyro * np.asarray(cal["k"]) + np.asarray(cal["b"]), atol=1e-9)
    rows = {(r.split(",")[0], r.split(",")[1]): float(r.split(",")[2]) for r in as_csv.splitlines()[1:] if r.split(",")[1]}
    assert rows[("k", "y")] == cal["k"][1] and rows[("b", "z")] == cal["b"][2]
    # the CLI writes the same file
    out = tmp_path / "from-cli.json"
    r2 = subprocess.run([*GYROCAL, "export", "--id", str(cal["id"]), "--format", "imucal", "--db", svc.db_url, "-o", str(out)], cwd=ROOT,
                        capture_output=True, text=True, timeout=60)
    assert r2.returncode == 0, r2.stderr
    assert json.loads(out.read_text()) == json.loads(path.read_text())
    ov_cli = subprocess.run([*GYROCAL, "export", "--id", str(cal["id"]), "--format", "openvins", "--db", svc.db_url], cwd=ROOT,
                            capture_output=True, text=True, timeout=60)
    assert ov_cli.returncode == 0 and ov_cli.stdout.strip() == ov.text.strip(), ov_cli.stderr
    r3 = subprocess.run([*GYROCAL, "export", "--id", "999999", "--db", svc.db_url], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r3.returncode != 0 and "no calibration #999999" in r3.stderr


def test_a_new_calibration_unlike_the_devices_history_is_flagged_before_accept(
    history: tuple[RunningService, list[dict[str, Any]]]
) -> None:
    from calib.simulator import SensorParams

    svc, _ = history
    sensor = SensorParams(k=np.array([1.08, 0.93, 1.12]), b=np.array([1.5, -2.0, 0.7]))

    def upload(seed: int, params: SensorParams, accept: bool) -> dict[str, Any]:
        rec, _ = simulate(seed, noise=0.03, params=params)
        buf = io.StringIO()
        write_native_csv(rec, buf)
        with svc.client() as c:
            r = c.post("/devices/worn-by-ward-7/calibrate", content=buf.getvalue(), headers={"Content-Type": "text/csv"},
                       params={"sensor_model": "ICM-20948", "firmware": "1.2.0"})
            assert r.status_code == 200, r.text
            if accept:
                assert c.post(f"/sessions/{r.json()['session_id']}/accept").status_code == 200
            return r.json()

    for seed in (21, 22):
        assert upload(seed, sensor, accept=True)["departures"] == []
    assert upload(23, sensor, accept=False)["departures"] == []
    knocked = upload(24, SensorParams(k=sensor.k * np.array([1.0, 1.0, 0.95]), b=sensor.b), accept=False)
    assert [(d["name"], d["axis"]) for d in knocked["departures"]] == [("k", "z")], knocked["departures"]
    # the session keeps it: the page shows it before anyone accepts
    with svc.client() as c:
        snap = c.get(f"/sessions/{knocked['session_id']}").json()
    assert snap["departures"] == knocked["departures"] and "2 earlier calibrations" in snap["departures"][0]["text"]


def test_a_simulated_wearable_dropped_between_sessions_is_flagged_in_its_live_session(tmp_path: Path) -> None:
    """mock-1 (scenario `dropped`, seed 1001: k_x 0.94) is calibrated twice and accepted; dropped, its x scale
    factor is 4 % higher at the third power-up, and that session's result names k_x before anyone accepts it."""
    db = f"sqlite:///{tmp_path / 'store.sqlite3'}"
    svc = RunningService(["--mock", "1", "--mock-speed", "40", "--mock-seed", "1", "--mock-scenario", "dropped"], db).start()
    try:
        last: dict[str, Any] = {}
        for n in range(3):
            with svc.client() as c:
                r = c.post("/devices/mock-1/calibrate", json={})
                assert r.status_code == 202, r.text
                sid = r.json()["session_id"]
            events = follow_events(svc.base, sid, {"done", "failed", "cancelled"}, timeout_s=90, last_event_id=0)
            last = events[-1]
            assert last["state"] == "done", last.get("reason")
            if n < 2:
                assert last["departures"] == []
                with svc.client() as c:
                    assert c.post(f"/sessions/{sid}/accept").status_code == 200
        assert [(d["name"], d["axis"]) for d in last["departures"]] == [("k", "x")], last["departures"]
        assert last["departures"][0]["value"] == pytest.approx(1.04 * last["departures"][0]["history_mean"], rel=2e-3)
    finally:
        svc.stop()


def test_a_device_is_due_when_never_calibrated_or_its_calibration_is_too_old(tmp_path: Path) -> None:
    db = f"sqlite:///{tmp_path / 'store.sqlite3'}"
    svc = RunningService(["--calibration-max-age-days", "0.00001", "--mock", "1"], db).start()  # 0.86 s: due almost at once
    try:
        rec, _ = simulate(41, noise=0.03)
        buf = io.StringIO()
        write_native_csv(rec, buf)
        with svc.client() as c:
            r = c.post("/devices/ward-1-unit-2/calibrate", content=buf.getvalue(), headers={"Content-Type": "text/csv"},
                       params={"sensor_model": "ICM-20948", "firmware": "1.2.0"})
            c.post(f"/sessions/{r.json()['session_id']}/accept").raise_for_status()
            fresh = c.get("/devices/ward-1-unit-2").json()["calibration_due"]
            time.sleep(1.0)
            old = c.get("/devices/ward-1-unit-2").json()["calibration_due"]
            listed = {d["id"]: d for d in c.get("/devices").json()}
        assert fresh == {"due": False, "reason": "its calibration is 0 days old, within the 1e-05 days allowed"}
        assert old["due"] and "more than the 1e-05 days allowed" in old["reason"]
        assert listed["mock-1"]["calibration_due"] == {"due": True, "reason": "never calibrated"}
        assert listed["ward-1-unit-2"]["calibration_due"]["due"]
    finally:
        svc.stop()


def _live_accepted(svc: RunningService) -> dict[str, Any]:
    """A guided session on the service's simulated wearable mock-1, run to its end and accepted: the calibration."""
    with svc.client() as c:
        sid = c.post("/devices/mock-1/calibrate", json={}).json()["session_id"]
    assert follow_events(svc.base, sid, {"done", "failed", "cancelled"}, timeout_s=90, last_event_id=0)[-1]["state"] == "done"
    with svc.client() as c:
        return dict(c.post(f"/sessions/{sid}/accept").json()["calibration"])


def test_a_calibration_records_its_sensor_power_up_and_temperature_and_is_applied_by_those_rules(tmp_path: Path) -> None:
    """A live session on the simulated wearable stores its serial, power-up and temperature with the calibration. The
    calibration in force then prefers the recording's power-up, warns across another one and beyond the temperature
    limit, and is refused for another sensor (409 from the API, an error from the CLI); the device is due once it
    reports another power-up than its calibration's."""
    from server.store import Store

    db = f"sqlite:///{tmp_path / 'store.sqlite3'}"
    svc = RunningService(["--mock", "1", "--mock-speed", "40", "--mock-seed", "3"], db).start()
    try:
        cal = _live_accepted(svc)
        with svc.client() as c:
            dev = c.get("/devices/mock-1").json()
        ident = cal["identity"]
        assert ident["device_id"] == "mock-1" and ident["serial"] == dev["serial"] and ident["serial"]
        assert ident["boot_count"] == 1 and ident["booted_at"] and 24.0 <= ident["temperature_c"] <= 28.0
        assert dev["power_up"]["boot_count"] == 1 and dev["calibration_due"]["due"] is False

        def in_force(**params: Any) -> Any:
            with svc.client() as c:
                return c.get("/devices/mock-1/calibration", params=params)

        same = in_force(boot_count=1, temperature_c=ident["temperature_c"] + 1).json()["in_force"]
        assert same["chosen_by"] == "same_power_up" and same["warnings"] == []
        assert same["identity_check"] == {"sensor": "same", "power_up": "same", "temperature": "same", "temperature_change_c": 1.0,
                                          "warnings": [], "refusal": None}
        later = in_force(boot_count=2, serial=ident["serial"], temperature_c=ident["temperature_c"] + 8).json()["in_force"]
        assert later["chosen_by"] == "latest_before" and len(later["warnings"]) == 2
        assert "power-up #1" in later["warnings"][0] and "power-up #2" in later["warnings"][0]
        assert "8.0 degC warmer" in later["warnings"][1]
        other = in_force(serial="NOT-" + ident["serial"])
        assert other.status_code == 409 and "another sensor" in other.json()["detail"]

        # a study recording with a temperature channel 8 degC above the calibration's: applied, with the warning
        rec, _ = simulate(12, noise=0.03)
        rec = rec.__class__(t=rec.t, gyro=rec.gyro, accel=rec.accel, temp=np.full(len(rec), ident["temperature_c"] + 8.0))
        src = tmp_path / "warm.csv"
        write_native_csv(rec, src)
        with svc.client() as c:
            r = c.post("/devices/mock-1/apply", content=src.read_text(), headers={"Content-Type": "text/csv"})
            assert r.status_code == 200, r.text
            assert any("8.0 degC warmer" in w for w in json.loads(r.headers["x-gyrocal-warnings"]))
            assert json.loads(r.headers["x-gyrocal-identity-check"])["temperature"] == "different"
            refused = c.post("/devices/mock-1/apply", content=src.read_text(), headers={"Content-Type": "text/csv"},
                             params={"serial": "B-0002"})
            assert refused.status_code == 409 and "another sensor" in refused.json()["detail"]
            exported = c.get(f"/calibrations/{cal['id']}").content

        # the CLI: the exported calibration carries its identity and is refused for another serial
        cal_file = tmp_path / "cal.json"
        cal_file.write_bytes(exported)
        run = [*GYROCAL, "apply", str(src), "--calibration", str(cal_file), "-o", str(tmp_path / "out.csv")]
        r = subprocess.run([*run, "--serial", "B-0002"], cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert r.returncode != 0 and "another sensor" in r.stderr and "Traceback" not in r.stderr
        r = subprocess.run([*run, "--boot-count", "2"], cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert r.returncode == 0 and "power-up #2" in r.stdout and "warmer" in r.stdout, r.stdout + r.stderr
        side = json.loads((tmp_path / "out.calibration.json").read_text())
        assert side["identity_check"]["power_up"] == "different" and side["calibration"]["identity"]["boot_count"] == 1

        # switched off and on: once the device reports its new power-up, it is due
        Store(db).upsert_device("mock-1", power_up={"boot_count": 2, "booted_at": datetime.now(UTC).isoformat(),
                                                    "temperature_c": 24.0})
        with svc.client() as c:
            due = c.get("/devices/mock-1").json()["calibration_due"]
        assert due["due"] and "switched on again" in due["reason"]
    finally:
        svc.stop()


def test_a_calibration_made_with_imucal_is_imported_into_the_history_and_applied(tmp_path: Path) -> None:
    """A Ferraris calibration written by the real imucal package is imported with the CLI (marked as imported, in
    force from then, once per file) and a gyrocal JSON file over the API; bad files are refused with why."""
    from imucal import FerrarisCalibrationInfo

    K_g = np.diag([1 / 1.05, 1 / 0.97, 1 / 1.02])  # imucal's K_g: counts per unit, here per deg/s
    info = FerrarisCalibrationInfo(
        K_a=np.eye(3), R_a=np.eye(3), b_a=np.zeros(3), K_g=K_g, R_g=np.eye(3), K_ga=np.zeros((3, 3)), b_g=np.array([0.4, -0.2, 0.1]),
        acc_unit="g", gyr_unit="deg/s", from_acc_unit="g", from_gyr_unit="deg/s", comment="bench turntable, 2026-11-02")
    path = tmp_path / "unit-5.imucal.json"
    info.to_json_file(path)
    db = f"sqlite:///{tmp_path / 'store.sqlite3'}"
    svc = RunningService([], db).start()
    try:
        subprocess.run([*GYROCAL, "operator", "--db", db, "add", "lab-tech"], cwd=ROOT, capture_output=True, check=True, timeout=60)
        run = [*GYROCAL, "import", str(path), "--device", "bench-5", "--db", db, "--serial", "IMU-5"]
        r = subprocess.run([*run, "--operator", "nobody"], cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert r.returncode != 0 and "no active operator 'nobody'" in r.stderr
        r = subprocess.run([*run, "--operator", "lab-tech"], cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert r.returncode == 0 and "imported for bench-5 as calibration #1 (imucal)" in r.stdout, r.stdout + r.stderr
        again = subprocess.run([*run, "--operator", "lab-tech"], cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert again.returncode != 0 and "imported for bench-5 already, as calibration #1" in again.stderr
        with svc.client() as c:
            cal = c.get("/devices/bench-5/calibration").json()
            assert cal["source"] == "import" and cal["method"] == "imported" and cal["identity"]["serial"] == "IMU-5"
            assert cal["k"] == pytest.approx([1.05, 0.97, 1.02], rel=1e-12)
            assert cal["b"] == pytest.approx(list(-np.diag([1.05, 0.97, 1.02]) @ np.array([0.4, -0.2, 0.1])), rel=1e-12)
            # it corrects a recording as imucal itself does
            rec, _ = simulate(14, noise=0.03)
            src = tmp_path / "study.csv"
            write_native_csv(rec, src)
            got = c.post("/devices/bench-5/apply", content=src.read_text(), headers={"Content-Type": "text/csv"})
            assert got.status_code == 200 and got.headers["x-gyrocal-calibration-id"] == "1"
            _, want = info.calibrate(rec.accel, rec.gyro, acc_unit="g", gyr_unit="deg/s")
            (tmp_path / "corrected.csv").write_text(got.text)
            assert np.allclose(read_recording(tmp_path / "corrected.csv").gyro, want, atol=1e-9)
            # gyrocal's own JSON over the API, its sensor named in the query
            ours = Correction(K=np.diag([1.01, 1.0, 0.99]), b=np.array([0.1, 0.2, 0.3])).to_json()
            r = c.post("/devices/bench-5/calibrations", content=json.dumps(ours), params={"name": "ours.json", "boot_count": 4},
                       headers={"Content-Type": "application/json"})
            assert r.status_code == 201, r.text
            imported = r.json()["calibration"]
            assert imported["id"] == 2 and imported["identity"]["boot_count"] == 4 and imported["k"] == [1.01, 1.0, 0.99]
            assert c.get("/devices/bench-5/calibration", params={"boot_count": 4}).json()["in_force"]["chosen_by"] == "same_power_up"
            kinds = {s["kind"] for s in c.get("/devices/bench-5/sessions").json()}
            assert kinds == {"import"}
            session = c.get(f"/sessions/{r.json()['session_id']}").json()
            assert (session["kind"], session["state"], session["decision"]) == ("import", "done", "accepted")
            for body, ctype, status, words in (
                ("{not json", "application/json", 400, "not JSON"),
                ('{"k": [1, 1]}', "application/json", 422, "three finite numbers"),
                ('{"cal_type": "Turntable"}', "application/json", 422, "Ferraris"),
                ("k,b", "text/csv", 415, "application/json"),
            ):
                bad = c.post("/devices/bench-5/calibrations", content=body, headers={"Content-Type": ctype})
                assert bad.status_code == status and words in bad.json()["detail"], (body, bad.text)
            assert len(c.get("/devices/bench-5/calibrations").json()) == 2  # nothing else was stored
        with svc.client(token=None) as anonymous:
            assert anonymous.post("/devices/bench-5/calibrations", content=json.dumps(ours),
                                  headers={"Content-Type": "application/json"}).status_code == 401
        from server.store import Store

        assert Store(db).verify().ok
    finally:
        svc.stop()


def test_a_verification_turn_after_accept_is_measured_and_kept_with_the_calibration(tmp_path: Path) -> None:
    """After Accept, one more turn on the simulated wearable (live) and an uploaded recording of one: each is measured
    with the calibration (360 degrees within its uncertainty, against the raw angle) and kept with it."""
    from server.store import Store

    db = f"sqlite:///{tmp_path / 'store.sqlite3'}"
    svc = RunningService(["--mock", "1", "--mock-speed", "40", "--mock-seed", "5"], db).start()
    try:
        cal = _live_accepted(svc)
        with svc.client() as c:
            started = c.post(f"/calibrations/{cal['id']}/verify", json={})
            assert started.status_code == 202 and started.headers["location"] == f"/verifications/{started.json()['verification_id']}"
            busy = c.post("/devices/mock-1/calibrate", json={})  # the device is in the verification: one thing at a time
            assert busy.status_code == 409
            prompts = []
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                run = c.get(started.headers["location"]).json()
                prompts.append(run["state"])
                if run["state"] in ("done", "failed"):
                    break
                time.sleep(0.1)
            assert run["state"] == "done", run
            live = run["result"]
            assert live["source"] == "live" and live["confirmed"] and abs(live["calibrated_deg"] - 360) < 3 * live["uncertainty_deg"] + 0.5
            assert abs(live["raw_deg"] - 360) > 5 and set(prompts) <= {"connecting", "still", "turn", "settle", "computing", "done"}
            # uploaded recordings of a turn: the live one's archived samples (confirmed again), another sensor's (not confirmed)
            own = c.get(f"/sessions/{live['session_id']}/recording")
            assert own.status_code == 200
            (tmp_path / "turn.csv").write_text(own.text)
            up = c.post(f"/calibrations/{cal['id']}/verify", content=own.text, headers={"Content-Type": "text/csv"})
            assert up.status_code == 201 and up.json()["source"] == "upload" and up.json()["confirmed"], up.text
            assert up.json()["calibrated_deg"] == pytest.approx(live["calibrated_deg"], abs=1e-6)
            rec, _ = simulate(5, noise=0.03)
            buf = io.StringIO()
            write_native_csv(rec.slice(0, 1100), buf)
            other = c.post(f"/calibrations/{cal['id']}/verify", content=buf.getvalue(), headers={"Content-Type": "text/csv"})
            assert other.status_code == 201 and not other.json()["confirmed"] and abs(other.json()["error_deg"]) > 1
            write_native_csv(rec.slice(0, 250), tmp_path / "still.csv")
            none = c.post(f"/calibrations/{cal['id']}/verify", content=(tmp_path / "still.csv").read_text(),
                          headers={"Content-Type": "text/csv"})
            assert none.status_code == 400 and "turn it once all the way round" in none.json()["detail"]
            assert c.post("/calibrations/9999/verify", json={}).status_code == 404
            kept = c.get(f"/calibrations/{cal['id']}/verifications").json()
            assert [v["source"] for v in kept] == ["upload", "upload", "live"] and kept[2]["session_id"] == live["session_id"]
            actions = [a["action"] for a in c.get("/audit", params={"device_id": "mock-1"}).json()]
            assert actions.count("calibration.verify") == 3
        # the CLI: a recorded turn verified and kept, and the device's history with its latest verification
        turn = tmp_path / "turn.csv"
        subprocess.run([*GYROCAL, "operator", "--db", db, "add", "lab-tech"], cwd=ROOT, capture_output=True, check=True, timeout=60)
        r = subprocess.run([*GYROCAL, "verify", str(turn), "--id", str(cal["id"]), "--operator", "lab-tech", "--db", db], cwd=ROOT,
                           capture_output=True, text=True, timeout=60)
        assert r.returncode == 0 and "confirmed: the calibration holds" in r.stdout, r.stdout + r.stderr
        r = subprocess.run([*GYROCAL, "verify", str(tmp_path / "still.csv"), "--id", str(cal["id"]), "--operator", "lab-tech",
                            "--db", db], cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert r.returncode != 0 and "Traceback" not in r.stderr
        r = subprocess.run([*GYROCAL, "history", "mock-1", "--db", db, "--json"], cwd=ROOT, capture_output=True, text=True, timeout=60)
        listed = json.loads(r.stdout)
        assert [c["id"] for c in listed["calibrations"]] == [cal["id"]] and listed["calibrations"][0]["departures"] == []
        assert listed["calibrations"][0]["verification"]["source"] == "upload" and listed["calibration_due"]["due"] is False
        r = subprocess.run([*GYROCAL, "history", "mock-1", "--db", db], cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert "verified" in r.stdout and "due: no" in r.stdout, r.stdout
        assert Store(db).verify().ok
    finally:
        svc.stop()


def test_ended_live_verifications_kept_in_memory_are_bounded(tmp_path: Path) -> None:
    """The service answers GET /verifications/{id} from memory for pages still polling; only the newest ended runs
    are kept (each is in the store), and a running one is never dropped."""
    from types import SimpleNamespace

    from server.config import Settings
    from server.service import KEEP_VERIFY_RUNS, Service

    svc = Service(Settings(db_url=f"sqlite:///{tmp_path / 'store.sqlite3'}"))
    try:
        running = SimpleNamespace(id="r0", state="turn", device=SimpleNamespace(id="dev-0"))
        svc.verify_runs["r0"] = running  # type: ignore[assignment]
        for i in range(1, KEEP_VERIFY_RUNS + 11):
            run = SimpleNamespace(id=f"r{i}", state="done", device=SimpleNamespace(id=f"dev-{i}"))
            svc.verify_runs[run.id] = run  # type: ignore[assignment]
            svc.active[run.device.id] = run.id
            svc.verification_ended(run)  # type: ignore[arg-type]
            assert run.device.id not in svc.active
        assert "r0" in svc.verify_runs and len(svc.verify_runs) == KEEP_VERIFY_RUNS + 1
        assert f"r{KEEP_VERIFY_RUNS + 10}" in svc.verify_runs and "r1" not in svc.verify_runs
    finally:
        svc.store.close()
