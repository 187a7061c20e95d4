"""One device, one holder: a guided session, a live verification and a write-back each claim the device before
their first await, so however the event loop interleaves two requests, one gets the device and the other 409.

The race test through the real server (test_write_back_api) leaves the interleaving to chance; here the store is
made slow on purpose so that every await inside a request gives the other request its chance to run."""

from __future__ import annotations

import asyncio
import itertools
import time
from collections.abc import Callable
from typing import Any

import httpx
import pytest

TOKEN = "claims-test-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def _slowed(fn: Callable[..., Any], seconds: float) -> Callable[..., Any]:
    def slow(*args: Any, **kwargs: Any) -> Any:
        time.sleep(seconds)  # runs in a worker thread: the event loop serves the other request meanwhile
        return fn(*args, **kwargs)

    return slow


STARTS = {
    "session": lambda cal_id: ("/devices/mock-1/calibrate", {}),
    "verify": lambda cal_id: (f"/calibrations/{cal_id}/verify", {}),
    "write": lambda cal_id: ("/devices/mock-1/calibration/write", {"calibration_id": cal_id}),
}


@pytest.mark.parametrize(("first", "second"), list(itertools.permutations(STARTS, 2)))
def test_two_starts_on_one_device_while_the_store_is_slow_give_one_device_holder(tmp_path, first: str, second: str) -> None:
    from server.config import Settings
    from server.devices import DeviceManager, load_simulators
    from server.main import create_app
    from server.service import Service

    settings = Settings(db_url=f"sqlite:///{tmp_path / 'store.sqlite3'}", api_token=TOKEN)
    devices = DeviceManager()
    simulators = load_simulators()
    devices.add_mocks(simulators, 1, speed=40.0, seed=3)
    svc = Service(settings, devices=devices)
    app = create_app(settings, svc)

    async def race() -> list[httpx.Response]:
        async with app.router.lifespan_context(app):
            async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://localhost", headers=AUTH,
                                         timeout=60) as c:
                imported = await c.post("/devices/mock-1/calibrations", content='{"k": [1.01, 0.99, 1.0], "b": [0.1, 0.0, -0.1]}',
                                        headers={"Content-Type": "application/json"})
                assert imported.status_code == 201, imported.text
                cal_id = imported.json()["calibration"]["id"]
                for name in ("current_calibration", "calibrations", "create_session", "calibration"):
                    setattr(svc.store, name, _slowed(getattr(svc.store, name), 0.3))
                answers = await asyncio.gather(*(c.post(path, json=body) for path, body in
                                                  (STARTS[first](cal_id), STARTS[second](cal_id))))
                for live in svc.sessions.values():
                    await live.shutdown()
                for run in list(svc.verify_runs.values()):
                    run.cancel()
                    await run.wait()
                return list(answers)

    answers = asyncio.run(race())
    codes = [r.status_code for r in answers]
    assert sorted(codes) in ([200, 409], [202, 409]), [r.text for r in answers]
    refused = answers[codes.index(409)].json()["detail"]
    assert "mock-1" in refused and ("in a calibration session or verification" in refused or "being written" in refused), refused
