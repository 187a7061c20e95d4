"""The model check over HTTP: POST /diagnose for an uploaded recording and GET /sessions/{id}/diagnosis
for a stored one (real `gyrocal serve`), and the queue behind them (in process)."""

from __future__ import annotations

import asyncio
import hashlib
import json
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from server_fixtures import API_TOKEN, RunningService, bad_csv_uploads, follow_events, native_csv

from calib.cli.main import main as gyrocal_main
from calib.simulator import simulate
from calib.simulator.concealed import draw_concealed

END = {"done", "failed", "cancelled"}
CSV = {"Content-Type": "text/csv"}


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RunningService]:
    db = tmp_path_factory.mktemp("diagnosis") / "store.sqlite3"
    svc = RunningService(["--mock", "2", "--mock-speed", "40", "--mock-seed", "3", "--mock-scenario", "normal,link_drop"],
                         f"sqlite:///{db}").start()
    yield svc
    svc.stop()


def imucal_csv(rec: Any) -> str:
    """imucal's layout: no time column, accelerometer in m/s^2."""
    rows = np.column_stack([rec.gyro, rec.accel * 9.80665])
    return "gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n"


def without_timing(d: dict[str, Any]) -> dict[str, Any]:
    d = json.loads(json.dumps(d))
    d["info"].pop("seconds", None)
    return d


def assert_same_json(a: Any, b: Any, path: str = "") -> None:
    """Equal structure and strings; numbers equal to 1e-9 relative (the same computation in two processes)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), (path, sorted(a), sorted(b) if isinstance(b, dict) else b)
        for k in a:
            assert_same_json(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), (path, a, b)
        for i, (x, y) in enumerate(zip(a, b, strict=False)):
            assert_same_json(x, y, f"{path}[{i}]")
    elif isinstance(a, float) or isinstance(b, float):
        assert a == pytest.approx(b, rel=1e-9, abs=1e-12), (path, a, b)
    else:
        assert a == b, (path, a, b)


def run_session(svc: RunningService, device: str) -> str:
    with svc.client() as c:
        r = c.post(f"/devices/{device}/calibrate", json={})
        assert r.status_code == 202, r.text
        sid = r.json()["session_id"]
        # while it runs there is nothing to check yet
        r = c.get(f"/sessions/{sid}/diagnosis")
        assert r.status_code == 409 and "running" in r.json()["detail"], r.text
    events = follow_events(svc.base, sid, END, timeout_s=90, last_event_id=0)
    assert events[-1]["state"] == "done", events[-1].get("reason")
    return sid


# -- uploads ---------------------------------------------------------------------------------------
def test_an_uploaded_recording_with_a_drift_is_diagnosed_as_the_command_line_does(service: RunningService, tmp_path: Path,
                                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    case = draw_concealed(2, "bias_drift")
    path = tmp_path / "drift.csv"
    path.write_text(native_csv(case.recording))
    with service.client() as c:
        r = c.post("/diagnose", content=path.read_bytes(), headers=CSV)
        assert r.status_code == 200, r.text
        assert r.headers["x-diagnosis-cache"] == "miss"
        d = r.json()
        again = c.post("/diagnose", content=path.read_bytes(), headers=CSV)
    assert again.status_code == 200 and again.headers["x-diagnosis-cache"] == "hit"
    assert again.json() == d
    assert d["effects"][0]["name"] == "bias_drift", [e["name"] for e in d["effects"]]
    for e in d["effects"]:
        assert e["fit"]["after"] < e["fit"]["before"] and e["evidence"]["summary"]
    assert d["mismatches"] and d["info"]["n_boot"] == 200  # the product default
    # the drift the service reports is the one hidden in the recording (within 4 standard errors)
    fitted = np.array(d["effects"][0]["parameters"]["rate_dps_per_s"])
    sd = np.array(d["effects"][0]["uncertainty"]["rate_dps_per_s"])
    assert np.all(np.abs(fitted - case.effect.rate_dps_per_s) < 4 * sd + 1e-5)
    # the same JSON as `gyrocal diagnose --json` on the same file
    assert gyrocal_main(["diagnose", str(path), "--json"]) == 0
    cli = json.loads(capsys.readouterr().out)
    assert_same_json(without_timing(d), without_timing(cli))


def test_a_null_recording_in_imucal_layout_names_nothing(service: RunningService) -> None:
    case = draw_concealed(0, None)
    body = imucal_csv(case.recording)
    with service.client() as c:
        r = c.post("/diagnose", content=body, headers=CSV)
        assert r.status_code == 400 and "fs" in r.json()["detail"], r.text  # imucal has no time column
        r = c.post("/diagnose", params={"fs": case.recording.fs, "layout": "imucal"}, content=body, headers=CSV)
    assert r.status_code == 200, r.text
    d = r.json()
    assert d["effects"] == [] and d["unexplained"] == []
    assert d["info"]["channels"]["accelerometer"] is True and d["info"]["sample_rate_hz"] == pytest.approx(case.recording.fs)
    # one turn per axis cannot show a speed-dependent scale factor: said so, with what would
    assert "scale_nonlinearity" in {n["name"] for n in d["not_identifiable"]}


def test_an_uploaded_multi_position_recording_is_diagnosed_on_its_re_orientations(service: RunningService) -> None:
    from calib.effects.axes import AxisMisalignment
    from calib.simulator.lab_scripts import multi_position_script

    script = multi_position_script(np.random.default_rng(12), n=16, first_rest_s=10.0, rest_s=3.0)
    rec, _ = simulate(12, noise=0.05, fs=50.0, script=script, accel_noise_g=0.005,
                      effects=[AxisMisalignment((0.0, 0.0, 0.03))])
    body = native_csv(rec)
    with service.client() as c:
        refused = c.post("/diagnose", params={"protocol": "paper"}, content=body, headers=CSV)
        r = c.post("/diagnose", params={"protocol": "multi-position"}, content=body, headers=CSV)
        bad = c.post("/diagnose", params={"sections": "{\"x_p\": {\"start\": 10}}"}, content=body, headers=CSV)
        unknown = c.post("/diagnose", params={"protocol": "turntable"}, content=body, headers=CSV)
    assert refused.status_code == 422 and "full turn" in refused.json()["detail"], refused.text
    assert r.status_code == 200, r.text
    d = r.json()
    assert d["info"]["protocol"]["used"] == "multi-position" and d["info"]["accelerometer"]["scale"]
    assert d["effects"][0]["name"] == "axis_misalignment", [e["name"] for e in d["effects"]]
    assert bad.status_code == 400 and "start and end" in bad.json()["detail"], bad.text
    assert unknown.status_code == 422, unknown.text


def test_the_report_of_an_upload_is_html(service: RunningService) -> None:
    rec, _ = simulate(21)
    with service.client() as c:
        r = c.post("/diagnose/report", content=native_csv(rec), headers=CSV)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"].startswith("text/html")
    assert "default-src 'none'" in r.headers["content-security-policy"]
    assert "Simulation against reality" in r.text and "data:image/png;base64," in r.text


def test_bad_uploads_get_a_4xx_with_a_reason(service: RunningService) -> None:
    bodies = bad_csv_uploads()
    still_only = bodies["no protocol"]
    with service.client() as c:
        for name, body in bodies.items():
            r = c.post("/diagnose", content=body, headers=CSV)
            assert 400 <= r.status_code < 500, (name, r.status_code, r.text)
            detail = r.json()["detail"]
            assert isinstance(detail, str) and len(detail) > 15, (name, detail)
        r = c.post("/diagnose", content=still_only, headers=CSV)
        assert r.status_code == 422 and "turn" in r.json()["detail"]  # names the missing stage
        r = c.post("/diagnose", content=b"<a/>", headers={"Content-Type": "application/xml"})
        assert r.status_code == 415 and "text/csv" in r.json()["detail"]
        r = c.post("/diagnose", params={"layout": "spreadsheet"}, content=still_only, headers=CSV)
        assert r.status_code == 422 and "imucal" in r.json()["detail"]
        r = c.post("/diagnose", params={"fs": -3}, content=still_only, headers=CSV)
        assert r.status_code == 422
        huge = b"t,gx,gy,gz\n" + b"0.000000001,0.0000001,0.00000001,0.000000001\n" * 800_000
        r = c.post("/diagnose", content=huge, headers=CSV)
        assert r.status_code == 413 and "MiB" in r.json()["detail"]
        r = c.post("/diagnose/report", content=b"prose\n", headers=CSV)
        assert r.status_code == 400 and r.json()["detail"]
        assert c.get("/health").json()["status"] == "ok"


# -- stored sessions -------------------------------------------------------------------------------
def test_a_live_session_is_diagnosed_once_and_then_kept(service: RunningService) -> None:
    sid = run_session(service, "mock-1")
    with service.client() as c:
        csv = c.get(f"/sessions/{sid}/recording")
        assert c.get(f"/sessions/{sid}/diagnosis/progress").json()["state"] == "idle"
        first = c.get(f"/sessions/{sid}/diagnosis")
        second = c.get(f"/sessions/{sid}/diagnosis")
        progress = c.get(f"/sessions/{sid}/diagnosis/progress").json()
        report = c.get(f"/sessions/{sid}/diagnosis/report")
        report_again = c.get(f"/sessions/{sid}/diagnosis/report")
    assert first.status_code == 200, first.text
    assert first.headers["x-diagnosis-cache"] == "miss" and second.headers["x-diagnosis-cache"] == "hit"
    assert first.headers["x-recording-sha256"] == hashlib.sha256(csv.content).hexdigest() == csv.headers["x-recording-sha256"]
    assert second.json() == first.json()
    d = first.json()
    # the simulated clinician did the protocol on a sensor that follows the model: nothing to find
    assert d["effects"] == [] and d["unexplained"] == [], (d["effects"], d["unexplained"])
    assert d["nominal"]["turns"] == 3 and d["info"]["samples"] == len(csv.text.splitlines()) - 1
    # the CSV archive has no header for it: clipping is judged against the range the wearable stated
    with service.client() as c:
        stated = c.get("/devices/mock-1").json()
    assert d["info"]["gyro_full_scale_dps"] == stated["info"]["gyro_full_scale_dps"] > 0
    assert progress["state"] == "done"
    assert report.status_code == 200 and "Simulation against reality" in report.text
    assert report_again.headers["x-diagnosis-cache"] == "hit" and report_again.text == report.text


def test_a_link_drop_shows_as_lost_samples(service: RunningService) -> None:
    sid = run_session(service, "mock-2")
    with service.client() as c:
        snap = c.get(f"/sessions/{sid}").json()
        r = c.get(f"/sessions/{sid}/diagnosis")
    assert r.status_code == 200, r.text
    d = r.json()
    assert snap["lost_samples"] > 0
    assert "sample_loss" in [e["name"] for e in d["effects"]]
    lost = [m for m in d["mismatches"] if m["statistic"] == "lost_samples"]
    assert lost and lost[0]["observed"] > 0


def test_an_uploaded_session_is_diagnosed_from_its_archive(service: RunningService) -> None:
    case = draw_concealed(2, "bias_drift")
    with service.client() as c:
        r = c.post("/devices/upload-d1/calibrate", content=native_csv(case.recording), headers=CSV)
        assert r.status_code == 200, r.text
        sid = r.json()["session_id"]
        d = c.get(f"/sessions/{sid}/diagnosis")
        cal = c.get("/devices/upload-d1/calibrations")
    assert d.status_code == 200, d.text
    assert d.json()["effects"][0]["name"] == "bias_drift"
    assert cal.json() == []  # a diagnosis writes nothing


def test_unknown_sessions_are_404(service: RunningService) -> None:
    with service.client() as c:
        for path in ("diagnosis", "diagnosis/report", "diagnosis/progress"):
            r = c.get(f"/sessions/0123456789abcdef0123456789abcdef/{path}")
            assert r.status_code == 404 and "no session" in r.json()["detail"]
            assert c.get(f"/sessions/not-a-session/{path}").status_code == 404


def test_reads_need_a_token_when_the_service_says_so(tmp_path: Path) -> None:
    svc = RunningService(["--auth-reads"], f"sqlite:///{tmp_path / 'store.sqlite3'}").start()
    try:
        rec, _ = simulate(5)
        body = native_csv(rec)
        with svc.client() as c:
            sid = c.post("/devices/upload-a1/calibrate", content=body, headers=CSV).json()["session_id"]
            assert c.get(f"/sessions/{sid}/diagnosis").status_code == 200
        with svc.client(token=None) as anon:
            assert anon.post("/diagnose", content=body, headers=CSV).status_code == 401
            assert anon.get(f"/sessions/{sid}/diagnosis").status_code == 401
            assert anon.get(f"/sessions/{sid}/diagnosis/report").status_code == 401
            # a page's link cannot send headers: the token in the address, as for the event stream
            r = anon.get(f"/sessions/{sid}/diagnosis/report", params={"access_token": API_TOKEN})
            assert r.status_code == 200 and "Simulation against reality" in r.text
    finally:
        svc.stop()


# -- the queue, in process -------------------------------------------------------------------------
def _slow(seconds: float, progress: Any = None) -> str:
    """Runs in a worker process: reports progress, then sleeps."""
    progress(0.5, "sleeping")
    time.sleep(seconds)
    return f"slept in {os.getpid()}"


async def test_the_queue_keeps_results_joins_equal_requests_and_refuses_beyond_its_size() -> None:
    from server.workers.diagnosis import Busy, DiagnosisQueue

    gate = asyncio.Event()
    calls: list[str] = []

    async def runner(job: Any, fn: Any, args: tuple[Any, ...], timeout_s: float) -> Any:
        calls.append(job.key)
        job.state = "running"
        await gate.wait()
        if args and args[0] == "fail":
            raise ValueError("bad recording")
        return f"value of {job.key}"

    q = DiagnosisQueue(workers=1, max_waiting=1, kept=2, runner=runner)
    a1 = asyncio.create_task(q.get("a", print))
    a2 = asyncio.create_task(q.get("a", print))  # the same recording: joins the first
    b = asyncio.create_task(q.get("b", print))
    while len(calls) < 2:
        await asyncio.sleep(0)
    with pytest.raises(Busy, match="try again"):
        await q.get("c", print)
    assert set(q.jobs) == {"a", "b"} and q.jobs["a"].state == "running"
    gate.set()
    assert await a1 == ("value of a", False) and await a2 == ("value of a", False) and await b == ("value of b", False)
    assert calls == ["a", "b"] and q.jobs == {}
    assert await q.get("a", print) == ("value of a", True)  # kept
    with pytest.raises(ValueError):
        await q.get("f", print, "fail")
    with pytest.raises(ValueError):
        await q.get("f", print, "fail")  # an error is not kept: it runs again
    assert calls == ["a", "b", "f", "f"]
    await q.get("c", print)
    await q.get("d", print)  # two kept: "a" is the least recently used and goes
    assert "a" not in q.results and "d" in q.results


async def test_a_worker_over_its_time_limit_is_killed_and_replaced() -> None:
    from server.workers.diagnosis import Worker

    w = Worker()
    seen: list[tuple[float, str]] = []
    try:
        assert (await w.call(_slow, (0.0,), lambda f, s: seen.append((f, s)), 60.0)).startswith("slept")
        first = w.pid
        assert seen == [(0.5, "sleeping")] and first is not None
        with pytest.raises(asyncio.TimeoutError):
            await w.call(_slow, (600.0,), lambda f, s: None, 0.5)
        assert w.pid is None  # the process was killed with the call
        assert (await w.call(_slow, (0.0,), lambda f, s: None, 60.0)) != f"slept in {first}"
    finally:
        w.stop()


async def test_a_busy_service_answers_503_with_retry_after(tmp_path: Path) -> None:
    from server.config import Settings
    from server.main import create_app
    from server.workers.diagnosis import DiagnosisQueue

    gate = asyncio.Event()

    async def runner(job: Any, fn: Any, args: tuple[Any, ...], timeout_s: float) -> Any:
        await gate.wait()
        return {"mismatches": [], "effects": [], "unexplained": [], "not_identifiable": [], "recalibration": None,
                "nominal": {}, "simulation_check": {}, "info": {}}, None

    app = create_app(Settings(db_url=f"sqlite:///{tmp_path / 'store.sqlite3'}"))
    app.state.diagnoser.queue = DiagnosisQueue(workers=1, max_waiting=0, runner=runner)
    rec, _ = simulate(3)
    one, two = native_csv(rec).encode(), native_csv(rec.slice(0, len(rec) - 1)).encode()
    async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://localhost") as c:
        first = asyncio.create_task(c.post("/diagnose", content=one, headers=CSV))
        while not app.state.diagnoser.queue.jobs:
            await asyncio.sleep(0.01)
        r = await c.post("/diagnose", content=two, headers=CSV)
        assert r.status_code == 503 and r.headers["retry-after"] and "try again" in r.json()["detail"]
        gate.set()
        assert (await first).status_code == 200
    app.state.service.store.close()


async def test_the_workers_stop_with_the_service(tmp_path: Path) -> None:
    from server.config import Settings
    from server.main import create_app

    app = create_app(Settings(db_url=f"sqlite:///{tmp_path / 'store.sqlite3'}"))
    rec, _ = simulate(6)
    async with app.router.lifespan_context(app):
        async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://localhost") as c:
            r = await c.post("/diagnose", content=native_csv(rec), headers=CSV)
            assert r.status_code == 200, r.text
        workers = [w.pid for w in app.state.diagnoser.queue._all if w.pid is not None]
        assert len(workers) == 1
    for pid in workers:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
