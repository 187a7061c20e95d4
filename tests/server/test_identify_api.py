"""POST /devices/{id}/identify over real HTTP on `gyrocal serve --mock`: the simulated wearable's light blinks for the
time asked; bad requests get a 4xx that says what to send; a model whose protocol has no such
command (Polar's PMD) is named, not failed."""

from __future__ import annotations

import time

import pytest
from server_fixtures import RunningService


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    db = tmp_path_factory.mktemp("identify") / "store.sqlite3"
    svc = RunningService(["--mock", "2", "--mock-speed", "20", "--mock-seed", "4"], f"sqlite:///{db}").start()
    yield svc
    svc.stop()


def test_a_wearable_asked_which_one_it_is_blinks_for_the_time_asked(service: RunningService) -> None:
    with service.client() as c:
        dev = c.get("/devices/mock-1").json()
        assert dev["identify"] == "blinks its light" and dev["simulated_identifying"] is False
        r = c.post("/devices/mock-1/identify", json={"seconds": 2})
        assert r.status_code == 200, r.text
        out = r.json()
        assert out == {"device_id": "mock-1", "seconds": 2, "how": "blinks its light",
                       "message": f"{dev['name'] or 'mock-1'} blinks its light for 2 s."}
        assert c.get("/devices/mock-1").json()["simulated_identifying"] is True
        assert c.get("/devices/mock-2").json()["simulated_identifying"] is False
        time.sleep(2.2)
        assert c.get("/devices/mock-1").json()["simulated_identifying"] is False
    # (a wearable streaming a session blinks too and streams on: tests/link/test_vendor_ble.py)


@pytest.mark.parametrize("body, status, words", [
    ({"seconds": 0}, 422, "seconds"), ({"seconds": 61}, 422, "seconds"), ({"blink": True}, 422, "blink"),
])
def test_a_bad_identify_request_says_what_to_send(service: RunningService, body: object, status: int, words: str) -> None:
    with service.client() as c:
        r = c.post("/devices/mock-1/identify", json=body)
        assert r.status_code == status and words in r.text, r.text
        r = c.post("/devices/no-such/identify", json={})
        assert r.status_code == 404 and "GET /devices" in r.json()["detail"], r.text


def test_a_wearable_that_cannot_blink_is_named_not_failed(tmp_path) -> None:  # type: ignore[no-untyped-def]
    svc = RunningService(["--mock", "1", "--mock-model", "polar-pmd", "--mock-speed", "5"],
                         f"sqlite:///{tmp_path / 'store.sqlite3'}").start()
    try:
        with svc.client() as c:
            dev = c.get("/devices/mock-1").json()
            assert dev["identify"] is None and any("no command to blink or buzz" in t for t in dev["limitations"])
            r = c.post("/devices/mock-1/identify", json={})
            assert r.status_code == 409 and "no command to blink or buzz" in r.json()["detail"], r.text
    finally:
        svc.stop()
