"""The service end to end over real HTTP: `gyrocal serve --mock` with simulated wearables and clinicians."""

from __future__ import annotations

import hashlib
import json
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from server_fixtures import GYROCAL, ROOT, RunningService, bad_csv_uploads, follow_events, native_csv, store_outage

from calib.io.readers import parse_recording_text
from calib.pipeline import calibrate
from calib.simulator import simulate
from calib.stages.stage import Stage

END = {"done", "failed", "cancelled"}
# mock-N performs SCENARIOS[N-1] in every session (seeded, so every run is the same)
SCENARIOS = ["normal", "normal", "moved_during_still", "wrong_axis", "too_fast", "stops_short", "link_drop", "packet_loss", "normal",
             "normal"]
SPEED = 40.0
# one try per turn: the scripted clinicians play a fixed script and never turn again, so each fault ends its session
MOCK_ARGS = ["--mock", str(len(SCENARIOS)), "--mock-speed", str(SPEED), "--mock-seed", "3", "--mock-scenario", ",".join(SCENARIOS),
             "--max-attempts", "1"]


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RunningService]:
    db = tmp_path_factory.mktemp("e2e") / "store.sqlite3"
    svc = RunningService(MOCK_ARGS, f"sqlite:///{db}").start()
    yield svc
    svc.stop()


def start_session(client: httpx.Client, device: str, **body: Any) -> str:
    r = client.post(f"/devices/{device}/calibrate", json=body)
    assert r.status_code == 202, r.text
    sid = r.json()["session_id"]
    assert r.headers["location"] == f"/sessions/{sid}"
    return sid


def run_to_end(svc: RunningService, device: str, **body: Any) -> tuple[str, list[dict[str, Any]]]:
    with svc.client() as c:
        sid = start_session(c, device, **body)
    events = follow_events(svc.base, sid, END, timeout_s=90, last_event_id=0)  # 0: from the first event
    return sid, events


def states(events: list[dict[str, Any]]) -> list[str]:
    out: list[str] = []
    for e in events:
        if not out or out[-1] != e["state"]:
            out.append(e["state"])
    return out


def test_live_session_to_done_accept_and_read_back(service: RunningService) -> None:
    sid, events = run_to_end(service, "mock-1")
    assert states(events) == ["connecting", "still", "turn_x", "turn_y", "turn_z", "computing", "done"], states(events)
    ids = [e["_sse_id"] for e in events]
    assert ids == sorted(set(ids)) and ids[0] == 1
    kinds = {e["_sse_event"] for e in events}
    assert {"state", "prompt", "progress", "angle"} <= kinds
    assert any(e["_sse_event"] == "angle" and abs(e["live"]["turn_angle_deg"] or 0) > 200 for e in events)
    final = events[-1]
    assert final["passed"] is True and final["result"]["k"] and all(c["ok"] for c in final["checks"])
    with service.client() as c:
        assert c.get("/devices/mock-1/calibration").status_code == 404  # nothing before accepting
        r = c.post(f"/sessions/{sid}/accept", json={"note": "first calibration"})
        assert r.status_code == 200, r.text
        assert c.post(f"/sessions/{sid}/accept").status_code == 409
        cal = c.get("/devices/mock-1/calibration").json()
        truth = c.get("/devices/mock-1").json()["simulated_truth"]
        history = c.get("/devices/mock-1/calibrations").json()
        csv = c.get(f"/sessions/{sid}/recording")
    assert cal["session_id"] == sid and cal["operator"] == "api" and cal["method"] == "closure"
    k, b = np.array(cal["k"]), np.array(cal["b"])
    k_std, b_std = np.array(cal["uncertainty"]["k"]), np.array(cal["uncertainty"]["b"])
    np.testing.assert_allclose(k, truth["k"], atol=2e-3)
    np.testing.assert_allclose(b, truth["b"], atol=0.02)
    # the stated uncertainty is honest: the error is within a few standard errors
    assert np.all(np.abs(k - truth["k"]) < 6 * k_std + 1e-5) and np.all(np.abs(b - truth["b"]) < 6 * b_std + 1e-4)
    assert [h["id"] for h in history] == [cal["id"]]
    # the archived recording reproduces the result exactly
    assert csv.status_code == 200 and csv.headers["x-recording-sha256"] == cal["recording_sha256"]
    assert hashlib.sha256(csv.content).hexdigest() == cal["recording_sha256"]
    rec = parse_recording_text(csv.content)
    stages = [Stage(s["kind"], s["start"], s["end"], s["start_s"], s["end_s"], s["axis"], s["angle_deg"], tuple(s["flags"]))
              for s in final["result"]["stages"]]
    again = calibrate(rec, method=cal["method"], stages=stages)
    np.testing.assert_allclose(again.k, k, rtol=0, atol=1e-8)


@pytest.mark.parametrize(
    "device, reason",
    [
        ("mock-3", "moved_during_pause"),  # a bump in the pause after the x turn
        ("mock-4", "wrong_axis"),  # z turned where y was asked for
        ("mock-5", "too_fast"),  # 0.6 s turns saturate the gyro
        ("mock-6", "out_of_tolerance"),  # z stopped at 320 deg: the turns no longer close after calibration
        ("mock-8", "sample_loss"),  # 2 % of packets lost
    ],
)
def test_fault_scenarios_end_failed_with_nothing_stored(service: RunningService, device: str, reason: str) -> None:
    sid, events = run_to_end(service, device)
    final = events[-1]
    assert final["state"] == "failed" and final["reason_code"] == reason, final["reason"]
    assert "start a new calibration" in final["reason"].lower()
    with service.client() as c:
        assert c.get(f"/devices/{device}/calibration").status_code == 404
        r = c.post(f"/sessions/{sid}/accept")
        assert r.status_code == 409 and "failed" in r.json()["detail"]
        assert c.post(f"/sessions/{sid}/discard").status_code == 200
        kept = c.get(f"/devices/{device}/sessions").json()
        assert c.get(f"/devices/{device}/calibrations").json() == []
    assert [(s["session_id"], s["state"], s["decision"]) for s in kept] == [(sid, "failed", "discarded")]


def test_a_second_failure_of_the_same_check_says_the_sensor_may_be_faulty(service: RunningService) -> None:
    """The z turn stopped short, once and again: the failure names the turn to redo; the sensor is suspected only
    when the device failed the same check the time before (read from its stored sessions)."""
    for _ in range(2):
        sid, events = run_to_end(service, "mock-6")
        with service.client() as c:
            c.post(f"/sessions/{sid}/discard")
    final = events[-1]
    assert final["reason_code"] == "out_of_tolerance" and "the time before: the sensor may be faulty" in final["reason"]


def test_link_drop_mid_turn_pauses_redoes_the_turn_and_ends_done(service: RunningService, tmp_path: Path) -> None:
    """The link drops halfway through the y turn: the session pauses, reconnects, asks for y again,
    and the simulated clinician, following that, redoes it; the gap is reported and left out."""
    sid, events = run_to_end(service, "mock-7")
    final = events[-1]
    assert states(events) == ["connecting", "still", "turn_x", "turn_y", "reconnecting", "turn_y", "turn_z", "computing", "done"], \
        final["reason"]
    # back on the interrupted turn: rest first, then the turn is asked for and made again
    i = next(i for i, e in enumerate(events) if e["state"] == "reconnecting")
    back = [(e["state"], e["phase"]) for e in events[i + 1:] if e["_sse_event"] in ("state", "prompt")]
    # "checking" may pass between two snapshots at 40x: the turn is recorded ("pause") once its closing rest is complete
    assert back[:4] == [("turn_y", p) for p in ("settle", "ready", "turning", "placing")], back
    assert back[4] in (("turn_y", "checking"), ("turn_y", "pause")), back
    assert [w["code"] for w in final["warnings"]] == ["link_lost", "link_restored"]
    assert "turn about Y will be done again" in final["warnings"][1]["message"]
    assert final["passed"] is True and all(c["ok"] for c in final["checks"])
    with service.client() as c:
        csv = c.get(f"/sessions/{sid}/recording")
        sections = c.get(f"/sessions/{sid}/sections")
        truth = c.get("/devices/mock-7").json()["simulated_truth"]
        assert c.post(f"/sessions/{sid}/accept").status_code == 200
        cal = c.get("/devices/mock-7/calibration").json()
        # one door: the recording with the stages the session took, uploaded, gives the calibration the session gave
        assert sections.status_code == 200 and sections.headers["content-disposition"].endswith(f'{sid}.sections.json"')
        upload = c.post("/devices/mock-7/calibrate", params={"sections": sections.text}, content=csv.content,
                        headers={"Content-Type": "text/csv"})
        assert upload.status_code == 200, upload.text
        assert (upload.json()["k"], upload.json()["b"]) == (cal["k"], cal["b"])
        assert c.post(f"/sessions/{upload.json()['session_id']}/discard").status_code == 200
        assert c.get(f"/sessions/{upload.json()['session_id']}/sections").status_code == 404  # the file's own are the user's
    # the gap is reported: the samples lost are exactly the one hole in the recording's sample counter,
    # where the device was out of range for 1.5 s
    rec = parse_recording_text(csv.content)
    holes = np.diff(rec.seq) - 1
    assert final["lost_samples"] > 0 and int(holes.sum()) == final["lost_samples"] and np.count_nonzero(holes) == 1
    gap = int(np.flatnonzero(holes)[0])
    assert rec.t[gap + 1] - rec.t[gap] >= 1.5
    # the gap is in the y turn made first; the calibration uses x before it and the y made again after it
    assert final["turns"]["x"]["end_s"] < rec.t[gap] < rec.t[gap + 1] < final["turns"]["y"]["start_s"]
    np.testing.assert_allclose(cal["k"], truth["k"], atol=2e-3)
    np.testing.assert_allclose(cal["b"], truth["b"], atol=0.02)
    # ... and so do the two files through the command line
    turns = [(s["label"], s["start"], s["end"]) for s in sections.json() if s["label"].endswith("_rot")]
    assert [t[0] for t in turns] == ["x_rot", "y_rot", "z_rot"]
    assert turns[1][1] > gap + 1  # the y turn made again, after the lost link
    (tmp_path / "rec.csv").write_bytes(csv.content)
    (tmp_path / "rec.sections.json").write_text(sections.text)
    out = subprocess.run([*GYROCAL, "calibrate", str(tmp_path / "rec.csv"), "--sections", str(tmp_path / "rec.sections.json"),
                          "--json"], cwd=ROOT, capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr
    cli = json.loads(out.stdout)
    assert (cli["k"], cli["b"]) == (cal["k"], cal["b"])


def test_two_sessions_in_a_row_on_one_wearable_both_end_done(service: RunningService) -> None:
    """Redo: a second session on the same simulated wearable, after its clock ran on past every time
    limit, is a new recording by the same hand on the same sensor and passes too."""
    finals = []
    for n in range(2):
        if n:
            # the device clock runs on between the sessions, beyond the 60 s limits (in device time)
            time.sleep(1.6 * 60.0 / SPEED)
        sid, events = run_to_end(service, "mock-10")
        finals.append(events)
        with service.client() as c:
            assert c.post(f"/sessions/{sid}/{'discard' if n == 0 else 'accept'}").status_code == 200
    (first, second), last = finals, finals[1][-1]
    start_2 = next(e["live"]["t_device_s"] for e in second if e["caused_by"])  # first batch of the second session
    assert start_2 - first[-1]["live"]["t_device_s"] > 60.0
    for events in finals:
        assert states(events) == ["connecting", "still", "turn_x", "turn_y", "turn_z", "computing", "done"], events[-1]["reason"]
        # no warning about the session; "service_late" is the service saying the busy computer held it up, which it
        # must say whenever that happens (tests/server/test_late_service.py)
        about_session = [w for w in events[-1]["warnings"] if w["code"] != "service_late"]
        assert events[-1]["passed"] is True and about_session == [] and events[-1]["lost_samples"] == 0
    assert first[-1]["result"]["k"] != last["result"]["k"]  # a new recording, not the first one again
    with service.client() as c:
        truth = c.get("/devices/mock-10").json()["simulated_truth"]
        kept = c.get("/devices/mock-10/sessions").json()
    np.testing.assert_allclose(last["result"]["k"], truth["k"], atol=2e-3)
    np.testing.assert_allclose(last["result"]["b"], truth["b"], atol=0.02)
    assert [(s["state"], s["decision"]) for s in kept] == [("done", "accepted"), ("done", "discarded")]


def test_one_session_per_device_cancel_and_sse_resume(service: RunningService) -> None:
    with service.client() as c:
        sid = start_session(c, "mock-2")
        r = c.post("/devices/mock-2/calibrate", json={})
        assert r.status_code == 409 and sid in r.json()["detail"]
        r = c.post(f"/sessions/{sid}/cancel")
        assert r.status_code == 200 and r.json()["state"] == "cancelled"
        assert c.post(f"/sessions/{sid}/cancel").status_code == 409
        assert c.post(f"/sessions/{sid}/accept").status_code == 409
        assert c.get("/devices/mock-2/calibration").status_code == 404
        sid2 = start_session(c, "mock-2")
    # a page that loses its connection resumes from the last event it saw
    first = follow_events(service.base, sid2, END, stop_after=6, last_event_id=0)
    rest = follow_events(service.base, sid2, END, last_event_id=first[-1]["_sse_id"], timeout_s=90)
    assert rest[0]["_sse_id"] == first[-1]["_sse_id"] + 1
    assert rest[-1]["state"] == "done"
    with service.client() as c:
        assert c.post(f"/sessions/{sid2}/discard").status_code == 200
        assert c.get("/devices/mock-2/calibration").status_code == 404
        audit = c.get("/audit", params={"device_id": "mock-2"}).json()
    actions = [a["action"] for a in audit]
    assert {"session.start", "session.cancel", "session.cancelled", "session.done", "session.discard"} <= set(actions)


def test_writes_need_a_signed_in_operator(service: RunningService) -> None:
    with service.client(token=None) as anon:
        r = anon.post("/devices/mock-9/calibrate", json={})
        assert r.status_code == 401 and "Bearer" in r.json()["detail"] and r.headers["www-authenticate"] == "Bearer"
        assert anon.get("/devices").status_code == 200  # reads are open by default
        assert anon.get("/audit").status_code == 401
    with service.client(token="not-a-token") as bad:
        assert bad.post("/devices/scan").status_code == 401
    out = subprocess.run([*GYROCAL, "operator", "--db", service.db_url, "add", "alice"], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    secret = out.stdout.strip().splitlines()[-1]
    with service.client(token=None) as c:
        assert c.post("/auth/login", json={"operator": "alice", "secret": secret + "x"}).status_code == 401
        r = c.post("/auth/login", json={"operator": "alice", "secret": secret})
        assert r.status_code == 200
        token = r.json()["token"]
    with service.client(token=token) as alice:
        assert alice.get("/auth/me").json() == {"operator": "alice"}
        found = alice.post("/devices/scan", params={"timeout": 0.5}).json()["devices"]
        assert {d["id"] for d in found} >= {"mock-1", "mock-9"}
        assert alice.post("/auth/logout").status_code == 204
        assert alice.get("/auth/me").status_code == 401


def test_uploaded_recordings_calibrate(service: RunningService, ferraris_csv: Path) -> None:
    rec, truth = simulate(11, noise=0.03)
    body = native_csv(rec)
    with service.client() as c:
        r = c.post("/devices/upload-1/calibrate", content=body, headers={"Content-Type": "text/csv"})
        assert r.status_code == 200, r.text
        res = r.json()
        np.testing.assert_allclose(res["k"], truth.k, atol=2e-3)
        np.testing.assert_allclose(res["b"], truth.b, atol=0.02)
        assert res["passed"] and res["state"] == "done" and len(res["stages"]) >= 7
        assert res["recording_sha256"] == hashlib.sha256(body.encode()).hexdigest()
        assert c.get("/devices/upload-1/calibration").status_code == 404
        r = c.post(f"/sessions/{res['session_id']}/accept")
        assert r.status_code == 409 and "names no sensor" in r.json()["detail"]  # an upload names its sensor first
        assert c.post(f"/sessions/{res['session_id']}/accept", json={"sensor_model": "LSM9DS1"}).status_code == 200
        current = c.get("/devices/upload-1/calibration").json()
        assert current["k"] == res["k"] and current["source"] == "upload" and current["sensor_model"] == "LSM9DS1"
        # a real recording in imucal's layout (102.4 Hz, no time column), against imucal's own result
        r = c.post("/devices/imu-7/calibrate", params={"fs": 102.4, "method": "closure"},
                   content=ferraris_csv.read_bytes(), headers={"Content-Type": "text/csv"})
        assert r.status_code == 200, r.text
        res = r.json()
        np.testing.assert_allclose(res["k"], [0.97284, 1.01788, 1.00169], atol=2e-3)
        np.testing.assert_allclose(res["b"], [0.5834, 0.3765, -0.0589], atol=0.02)
        r = c.post("/devices/imu-7/calibrate", params={"fs": 102.4, "method": "paper"},
                   content=ferraris_csv.read_bytes(), headers={"Content-Type": "text/csv"})
        assert r.status_code == 200 and r.json()["method"] == "paper"
        assert c.get("/devices/imu-7").json()["transport"] is None


def test_a_recording_turned_about_some_axes_is_shown_incomplete_and_never_becomes_the_calibration(service: RunningService) -> None:
    """Turned about y only: y is calibrated, x and z are named as not determined; the result cannot be accepted and
    the device keeps the calibration it had."""
    from calib.simulator import ProtocolScript, Still, Turn

    full, _ = simulate(12, noise=0.03)
    partial, truth = simulate(13, noise=0.03, script=ProtocolScript((Still(3.0), Turn("y", 360.0), Still(3.0),
                                                                     Turn("y", 360.0), Still(3.0))))
    bodies = [native_csv(rec) for rec in (full, partial)]
    with service.client() as c:
        first = c.post("/devices/upload-part/calibrate", content=bodies[0], headers={"Content-Type": "text/csv"}).json()
        assert c.post(f"/sessions/{first['session_id']}/accept", json={"sensor_model": "LSM9DS1"}).status_code == 200
        before = c.get("/devices/upload-part/calibration").json()
        r = c.post("/devices/upload-part/calibrate", content=bodies[1], headers={"Content-Type": "text/csv"})
        assert r.status_code == 200, r.text
        res = r.json()
        assert res["k"][0] is None and res["k"][2] is None and res["b"][0] is None and res["b"][2] is None
        assert abs(res["k"][1] - truth.k[1]) < 5 * res["uncertainty"]["k"][1]
        assert res["quality"]["undetermined_axes"] == ["x", "z"] and not res["passed"]
        assert res["reason"].startswith("The calibration is incomplete: there was no usable full turn about X and Z")
        failed = [ch for ch in c.get(f"/sessions/{res['session_id']}").json()["checks"] if not ch["ok"]]
        assert [(ch["name"], ch["axis"]) for ch in failed] == [("k", "x"), ("k", "z")]
        r = c.post(f"/sessions/{res['session_id']}/accept", json={"sensor_model": "LSM9DS1"})
        assert r.status_code == 409
        after = c.get("/devices/upload-part/calibration").json()
        assert (after["id"], after["k"], after["b"]) == (before["id"], before["k"], before["b"])


def test_an_uploaded_multi_position_recording_is_calibrated_from_its_re_orientations(service: RunningService) -> None:
    from calib.simulator.lab_scripts import multi_position_script

    rng = np.random.default_rng(21)
    rec, truth = simulate(21, noise=0.05, fs=100.0, script=multi_position_script(rng, n=14, first_rest_s=20.0))
    body = native_csv(rec)
    with service.client() as c:
        r = c.post("/devices/upload-mp/calibrate", content=body, headers={"Content-Type": "text/csv"})
        assert r.status_code == 200, r.text
        res = r.json()
        assert res["protocol"] == "multi-position" and res["method"] == "multi-position"
        np.testing.assert_allclose(res["k"], truth.k, atol=2e-3)
        assert res["accelerometer"]["n_rests"] == 15 and len(res["accelerometer"]["identified"]) == 9
        r = c.post("/devices/upload-mp/calibrate", params={"protocol": "paper"}, content=body,
                   headers={"Content-Type": "text/csv"})
        assert r.status_code == 422 and "turn" in r.json()["detail"]  # asked for the paper's turns: refused, with the reason
        r = c.post("/devices/upload-mp/calibrate", params={"protocol": "astrology"}, content=body,
                   headers={"Content-Type": "text/csv"})
        assert r.status_code == 422


def test_an_uploaded_imucal_counts_file_with_sections_is_calibrated_as_ferraris(service: RunningService, real_data: Path) -> None:
    body = (real_data / "imucal" / "annotated_session.csv").read_bytes()
    counts = {"fs": 204.8, "gyro_counts_per_dps": 16.4, "accel_counts_per_g": 2048}
    with service.client() as c:
        r = c.post("/devices/imucal-a/calibrate", params=counts, content=body, headers={"Content-Type": "text/csv"})
        assert r.status_code == 200, r.text
        res = r.json()
        assert res["protocol"] == "ferraris" and res["quality"]["protocol"]["sections"] == 9
        np.testing.assert_allclose(res["k"], 16.4 / np.array([16.6777, 16.1879, 16.2534]), atol=5e-4)
        r = c.post("/devices/imucal-a/calibrate", params={**counts, "method": "ferraris"}, content=body,
                   headers={"Content-Type": "text/csv"})
        assert r.status_code == 200 and r.json()["method"] == "ferraris"
        r = c.post("/devices/imucal-a/calibrate", params={"fs": 204.8}, content=body, headers={"Content-Type": "text/csv"})
        assert r.status_code == 400 and "gyro_counts_per_dps" in r.json()["detail"]

    example = (real_data / "imucal" / "example_ferraris_session.csv").read_bytes()
    sections = (real_data / "imucal" / "example_ferraris_session_list.json").read_text()
    with service.client() as c:
        r = c.post("/devices/imucal-b/calibrate", params={"fs": 102.4, "sections": sections, "protocol": "ferraris"},
                   content=example, headers={"Content-Type": "text/csv"})
        assert r.status_code == 200, r.text
        assert r.json()["quality"]["protocol"]["sections"] == 9
        np.testing.assert_allclose(r.json()["k"], [0.97284, 1.01788, 1.00169], atol=5e-4)
        r = c.post("/devices/imucal-b/calibrate", params={"fs": 102.4, "sections": '{"x_p": {"start": 0}}'},
                   content=example, headers={"Content-Type": "text/csv"})
        assert r.status_code == 400 and "section 'x_p'" in r.json()["detail"]
        # the longest section list the URL carries, percent-encoded at 12 bytes a character, and one more character
        r = c.post("/devices/imucal-b/calibrate", params={"fs": 102.4, "sections": "\U0001F600" * 4001},
                   content=example, headers={"Content-Type": "text/csv"})
        assert r.status_code == 422 and "at most 4000 characters" in r.json()["detail"]


def test_imu_tk_s_two_files_are_uploaded_and_calibrated_from_their_re_orientations(service: RunningService,
                                                                                    real_data: Path) -> None:
    """imu_tk's Xsens session as its two files, in one multipart body: the same calibration as from the command line;
    a part missing, a file that is not imu_tk's, or two files where one CSV was meant, each refused with a reason."""
    from calib.estimators.multi_position.estimator import calibrate_multi_position
    from calib.io.imu_tk import read_imu_tk

    folder = real_data / "imu_tk"
    gyro, accel = (folder / "xsens_gyro.mat").read_bytes(), (folder / "xsens_acc.mat").read_bytes()
    local = calibrate_multi_position(read_imu_tk(folder / "xsens_gyro.mat", folder / "xsens_acc.mat"))
    with service.client() as c:
        r = c.post("/devices/xsens-1/calibrate", params={"layout": "imu_tk"},
                   files={"gyro": ("xsens_gyro.mat", gyro), "accel": ("xsens_acc.mat", accel)})
        assert r.status_code == 200, r.text
        res = r.json()
        assert res["protocol"] == "multi-position" and len(res["quality"]["gravity_residual_deg"]) == 37
        np.testing.assert_allclose(res["k"], local.k, rtol=1e-9)
        assert res["quality"]["constraint_fit"]["motions"]["p_value"] > 0.1
        # imu_tk's example sensitivities read this Xsens 31 % low: calibrated, but outside what a wearable may carry
        stored = c.get(f"/sessions/{res['session_id']}").json()
        assert stored["state"] == "failed" and "k_x = 1.3087 (allowed 0.8 to 1.2)" in stored["reason"]
        r = c.post("/devices/xsens-1/calibrate", params={"layout": "imu_tk"}, files={"gyro": ("xsens_gyro.mat", gyro)})
        assert r.status_code == 422 and "no part 'accel'" in r.json()["detail"]
        r = c.post("/devices/xsens-1/calibrate", params={"layout": "imu_tk"},
                   files={"gyro": ("g.csv", b"t,gx,gy,gz\n0,1,2,3\n"), "accel": ("xsens_acc.mat", accel)})
        assert r.status_code == 400 and "rows 't x y z'" in r.json()["detail"]
        r = c.post("/devices/xsens-1/calibrate", files={"gyro": ("xsens_gyro.mat", gyro), "accel": ("xsens_acc.mat", accel)})
        assert r.status_code == 415 and "layout=imu_tk" in r.json()["detail"]
        r = c.post("/devices/xsens-1/calibrate", params={"layout": "imu_tk"}, content=gyro, headers={"Content-Type": "text/csv"})
        assert r.status_code == 400 and "'gyro' and 'accel'" in r.json()["detail"]
        r = c.post("/diagnose", params={"layout": "imu_tk"}, content=gyro, headers={"Content-Type": "text/csv"})
        assert r.status_code == 422 and "choose auto, native or imucal" in r.json()["detail"]  # read by calibrate only
    # a form any web page could send: without an operator's Authorization header it is refused before it is read
    with service.client(token=None) as c:
        r = c.post("/devices/xsens-2/calibrate", params={"layout": "imu_tk"},
                   files={"gyro": ("xsens_gyro.mat", gyro), "accel": ("xsens_acc.mat", accel)})
        assert r.status_code == 401
        assert c.get("/devices/xsens-2").status_code == 404


def test_garbage_uploads_get_a_4xx_with_a_reason(service: RunningService) -> None:
    bodies = bad_csv_uploads()
    with service.client() as c:
        for name, body in bodies.items():
            r = c.post("/devices/garbage-1/calibrate", content=body, headers={"Content-Type": "text/csv"})
            assert 400 <= r.status_code < 500, (name, r.status_code, r.text)
            detail = r.json()["detail"]
            assert isinstance(detail, str) and len(detail) > 15, (name, detail)
        r = c.post("/devices/garbage-1/calibrate", content=b"<a/>", headers={"Content-Type": "application/xml"})
        assert r.status_code == 415
        r = c.post("/devices/mock-9/calibrate", content=b"{not json", headers={"Content-Type": "application/json"})
        assert r.status_code == 422
        r = c.post("/devices/mock-9/calibrate", json={"method": "astrology"})
        assert r.status_code == 422 and "closure" in r.json()["detail"]
        r = c.post("/devices/mock-9/calibrate", json={"surprise": 1})
        assert r.status_code == 422
        r = c.post("/devices/garbage-1/calibrate", params={"method": "nope"}, content=b"t,gx,gy,gz\n", headers={"Content-Type": "text/csv"})
        assert r.status_code == 422
        huge = b"t,gx,gy,gz\n" + b"0.000000001,0.0000001,0.00000001,0.000000001\n" * 800_000
        r = c.post("/devices/garbage-1/calibrate", content=huge, headers={"Content-Type": "text/csv"})
        assert r.status_code == 413 and "MiB" in r.json()["detail"]
        assert c.get("/devices/no-such-device").status_code == 404
        assert c.get("/sessions/0123456789abcdef0123456789abcdef").status_code == 404
        assert c.get("/sessions/not-an-id/events").status_code == 404
        assert c.get("/health").json()["status"] == "ok"
        assert c.get("/devices/garbage-1").status_code == 404  # refused uploads leave no trace but the log


CALIBRATION_INSERT = [("calibrations", "INSERT", None)]


def test_restart_keeps_history_and_a_failed_store_write_changes_nothing(service_store: tuple[str, str]) -> None:
    """Against SQLite and PostgreSQL: accept, restart the service, fail a write, retry it."""
    store_url, service_url = service_store
    svc = RunningService(["--mock", "1", "--mock-speed", "40", "--mock-seed", "5"], service_url).start()
    try:
        sid1, events = run_to_end(svc, "mock-1")
        assert events[-1]["state"] == "done"
        with svc.client() as c:
            first = c.post(f"/sessions/{sid1}/accept").json()["calibration"]
            running = start_session(c, "mock-1")
    finally:
        svc.stop()  # with a session running
    svc = RunningService(["--mock", "1", "--mock-speed", "40", "--mock-seed", "5"], service_url).start()
    try:
        with svc.client() as c:
            current = c.get("/devices/mock-1/calibration").json()
            assert current.pop("in_force")["warnings"] == [] and current == first
            assert [h["id"] for h in c.get("/devices/mock-1/calibrations").json()] == [first["id"]]
            interrupted = c.get(f"/sessions/{running}").json()
            assert interrupted["state"] in ("cancelled", "failed") and interrupted["reason"]
            assert c.get(f"/sessions/{sid1}").json()["decision"] == "accepted"
        sid2, events = run_to_end(svc, "mock-1")
        assert events[-1]["state"] == "done"
        store_outage(store_url, True, CALIBRATION_INSERT)
        with svc.client() as c:
            r = c.post(f"/sessions/{sid2}/accept")
            assert r.status_code == 503 and "previous calibration stays current" in r.json()["detail"]
            assert c.get("/devices/mock-1/calibration").json()["id"] == first["id"]
            store_outage(store_url, False, CALIBRATION_INSERT)
            r = c.post(f"/sessions/{sid2}/accept")
            assert r.status_code == 200, r.text
            second = r.json()["calibration"]
            assert c.get("/devices/mock-1/calibration").json()["id"] == second["id"] != first["id"]
            assert [h["id"] for h in c.get("/devices/mock-1/calibrations").json()] == [second["id"], first["id"]]
    finally:
        svc.stop()


def test_a_session_a_newer_gyrocal_ended_for_a_reason_this_one_does_not_know_is_still_shown(service: RunningService) -> None:
    """The gateways of one fleet share a store and are upgraded one at a time: a session a newer version ended with a
    reason code this one does not know yet is shown, and its device too, with the reason in words and no code."""
    from server.store import SessionEnd, Store

    store = Store(service.db_url)
    sid = hashlib.sha256(b"newer").hexdigest()[:32]
    store.upsert_device("unit-from-a-newer-room")
    store.create_session(sid, "unit-from-a-newer-room", "live", "connecting", "closure", "alice", "9.0.0")
    store.finish_session(sid, SessionEnd("failed", "a_reason_of_a_newer_gyrocal", "What the newer gyrocal said."))
    store.close()
    with service.client() as c:
        shown = c.get(f"/sessions/{sid}")
        assert shown.status_code == 200, shown.text
        assert (shown.json()["state"], shown.json()["reason_code"], shown.json()["reason"]) == \
            ("failed", None, "What the newer gyrocal said.")
        device = c.get("/devices/unit-from-a-newer-room")
        assert device.status_code == 200, device.text
        assert [(r["id"], r["reason_code"]) for r in device.json()["recent_sessions"]] == [(sid, None)]


def test_an_upload_without_a_stated_heading_spread_learns_it_from_its_turns(service: RunningService) -> None:
    from calib.effects.placement import PlacementError

    rec, _ = simulate(23, noise=0.05, effects=[PlacementError(0.5, heading_std_deg=0.5)])
    with service.client() as c:
        r = c.post("/devices/upload-heading/calibrate", content=native_csv(rec), headers={"Content-Type": "text/csv"})
    assert r.status_code == 200, r.text
    res = r.json()
    heading = res["quality"]["placement"]["heading"]
    assert heading["source"] == "estimated" and heading["turns"] == 3 and 0 < heading["spread_deg"] < 3
    assert res["uncertainty"]["k_dof"] is not None and len(res["uncertainty"]["k_dof"]) == 3
