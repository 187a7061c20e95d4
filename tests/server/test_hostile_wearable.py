"""A wearable that sends what the service cannot read, or values no working sensor gives: the session names the
wearable (its data, its sensor), never the radio link or the clinician's hands."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

TOKEN = "hostile-wearable-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


async def _session_with(tmp_path: Path, mid_session: Any, speed: float = 10.0, body: dict[str, Any] | None = None) -> dict[str, Any]:
    """A guided session on mock-1 through the real app (in process, so the test can reach the simulated wearable);
    ``mid_session(wearable)`` runs once the first turn is asked for. The session's end as the API shows it."""
    from server.config import Settings
    from server.devices import DeviceManager, load_simulators
    from server.main import create_app
    from server.service import Service

    settings = Settings(db_url=f"sqlite:///{tmp_path / 'store.sqlite3'}", api_token=TOKEN)
    devices = DeviceManager()
    devices.add_mocks(load_simulators(), 1, speed=speed, seed=4, scenarios=["normal"])
    svc = Service(settings, devices=devices)
    app = create_app(settings, svc)
    async with app.router.lifespan_context(app):
        async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://localhost", headers=AUTH,
                                     timeout=60) as c:
            r = await c.post("/devices/mock-1/calibrate", json=body or {})
            assert r.status_code == 202, r.text
            sid = r.json()["session_id"]
            for _ in range(600):
                snap = (await c.get(f"/sessions/{sid}")).json()
                if snap["state"] == "turn_x":
                    break
                await asyncio.sleep(0.05)
            assert snap["state"] == "turn_x", snap
            mid_session(devices.devices["mock-1"].peripheral)
            for _ in range(1200):
                snap = (await c.get(f"/sessions/{sid}")).json()
                if snap["state"] in ("done", "failed", "cancelled"):
                    return dict(snap)
                await asyncio.sleep(0.05)
            raise AssertionError(f"the session did not end: {snap}")


def test_a_wearable_sending_a_format_this_version_cannot_read_is_named_as_such(tmp_path: Path) -> None:
    end = asyncio.run(_session_with(tmp_path, lambda w: w.corrupt_next_packets(10**9)))
    assert end["state"] == "failed" and end["reason_code"] == "unreadable_data", end
    assert "cannot read" in end["reason"] and "a packet format this version of gyrocal does not know" in end["reason"]
    assert "firmware" in end["reason"] and "not the radio link" in end["reason"]
    assert not any(w["code"] in ("link_lost", "no_data") for w in end["warnings"]), end["warnings"]


def _faulty(axis: int | None = None, gyro_value: float | None = None, accel_scale: float | None = None) -> Any:
    from test_server_session import STANDARD, sim

    rec, _ = sim(STANDARD)
    if axis is not None:
        rec.gyro[:, axis] = gyro_value
    if accel_scale is not None:
        rec.accel[:] *= accel_scale
    return rec


def _run_on(rec: Any) -> Any:
    from test_server_session import Run

    run = Run(max_attempts=3)
    run.feed(rec)
    return run.s


def test_a_gyroscope_axis_stuck_at_its_limit_is_the_sensor_s_fault_not_the_hands() -> None:
    s = _run_on(_faulty(axis=1, gyro_value=-32768 / 65.5))  # the raw count stuck at -32768
    assert s.state == "failed" and s.reason_code == "sensor_fault", (s.reason_code, s.reason)
    assert "The gyroscope's Y axis stays at its limit (-500 deg/s of ±500)" in s.reason and "repair" in s.reason
    assert "not the way the device was held or turned" in s.reason


def test_a_gyroscope_axis_stuck_at_a_constant_rate_is_the_sensor_s_fault() -> None:
    s = _run_on(_faulty(axis=2, gyro_value=37.5))
    assert s.reason_code == "sensor_fault" and "Z axis reads exactly +37.5 deg/s, unchanging" in s.reason


def test_an_accelerometer_reading_4_g_at_rest_is_named() -> None:
    s = _run_on(_faulty(accel_scale=-4.0))
    assert s.reason_code == "sensor_fault" and "The accelerometer reads 4.00 g while the device rests" in s.reason


def test_a_working_sensor_is_never_called_faulty() -> None:
    from test_server_session import STANDARD, sim

    for seed in range(1, 6):
        rec, _ = sim(STANDARD, seed=seed)
        s = _run_on(rec)
        assert s.state == "computing", (seed, s.reason_code, s.reason)


segment = st.tuples(
    st.sampled_from(["rest", "constant", "noise", "rail", "turn"]),
    st.floats(0.2, 6.0),  # seconds
    st.integers(0, 2),  # axis
    st.floats(-600.0, 600.0),  # a rate (deg/s) or an amplitude
)


@settings(max_examples=40, deadline=None)
@given(st.lists(segment, min_size=1, max_size=12), st.integers(0, 2**32 - 1))
def test_a_live_session_fed_any_sensor_stream_never_raises_and_always_says_why_it_ended(segments: list[Any], seed: int) -> None:
    """Whatever values the int16 samples take (stuck, saturated, wild, turning), the session stays in a known state,
    and a session that ends says why with one of its documented reasons."""
    from test_server_session import FS, Run

    from server.live.codes import END_STATES, STEPS, EndReason, State

    rng = np.random.default_rng(seed)
    parts = []
    for kind, dur, axis, value in segments:
        n = max(1, int(dur * FS))
        g = rng.normal(0.0, 0.03, (n, 3))
        if kind == "constant":
            g[:, axis] = round(value * 65.5) / 65.5
        elif kind == "noise":
            g += rng.normal(0.0, abs(value), (n, 3))
        elif kind == "rail":
            g[:, axis] = np.sign(value or 1.0) * 32768 / 65.5
        elif kind == "turn":
            g[:, axis] += value
        parts.append(np.clip(np.round(g * 65.5), -32768, 32767) / 65.5)
    gyro = np.concatenate(parts)
    accel = np.tile([0.0, 0.0, 1.0], (len(gyro), 1)) + rng.normal(0, 0.002, (len(gyro), 3))
    run = Run(max_attempts=3)
    for i in range(0, len(gyro), 3):
        j = min(len(gyro), i + 3)
        run.s.feed(np.arange(i, j) / FS, gyro[i:j], accel[i:j], np.arange(i, j))
        assert run.s.state in {*STEPS, *END_STATES, State.RECONNECTING}
        if run.s.finished:
            break
    if run.s.finished:
        assert run.s.reason_code is None or run.s.reason_code in set(EndReason)
        assert run.s.state == State.DONE or run.s.reason
