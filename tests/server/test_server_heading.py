"""The hand's heading spread at a site: learned from each recording's turns, or stated per service (``serve
--heading-prior-deg``) and per upload (``heading_prior_deg``); every result says which it carried and whence."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from server_fixtures import RunningService, follow_events, native_csv

from calib.effects.placement import PlacementError
from calib.simulator import simulate

END = ("done", "failed", "cancelled")


def _csv(seed: int) -> str:
    rec, _ = simulate(seed, noise=0.05, effects=[PlacementError(0.5, heading_std_deg=0.5)])
    return native_csv(rec)


def _upload(svc: RunningService, device: str, **params: object) -> dict:
    with svc.client() as c:
        r = c.post(f"/devices/{device}/calibrate", params=params, content=_csv(21), headers={"Content-Type": "text/csv"})
    assert r.status_code == 200, r.text
    return r.json()


@pytest.fixture(scope="module")
def stated(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RunningService]:
    db = tmp_path_factory.mktemp("heading") / "store.sqlite3"
    svc = RunningService(["--mock", "1", "--mock-speed", "40", "--mock-seed", "5", "--heading-prior-deg", "0.2"],
                         f"sqlite:///{db}").start()
    yield svc
    svc.stop()


def test_the_services_stated_spread_is_carried_by_live_sessions_and_uploads(stated: RunningService) -> None:
    with stated.client() as c:
        r = c.post("/devices/mock-1/calibrate", json={})
        assert r.status_code == 202, r.text
        sid = r.json()["session_id"]
    events = follow_events(stated.base, sid, END, timeout_s=90, last_event_id=0)
    final = events[-1]
    assert final["state"] == "done", {k: final.get(k) for k in ("reason_code", "reason", "warnings", "lost_samples", "checks")}
    heading = final["result"]["quality"]["placement"]["heading"]
    assert heading["source"] == "stated" and heading["spread_deg"] == 0.2
    assert _upload(stated, "up-1")["quality"]["placement"]["heading"]["spread_deg"] == 0.2  # the service's
    own = _upload(stated, "up-2", heading_prior_deg=0.05)["quality"]["placement"]["heading"]  # the upload's own
    assert own["source"] == "stated" and own["spread_deg"] == 0.05


def test_an_upload_learns_the_spread_unless_it_states_one_and_bad_ones_are_named(stated: RunningService) -> None:
    with stated.client() as c:
        r = c.post("/devices/up-3/calibrate", params={"heading_prior_deg": -1}, content=_csv(22),
                   headers={"Content-Type": "text/csv"})
        assert r.status_code == 422 and "heading_prior_deg" in r.text
        r = c.post("/devices/up-3/calibrate", params={"heading_prior_deg": 0.1, "method": "paper"}, content=_csv(22),
                   headers={"Content-Type": "text/csv"})
        assert 400 <= r.status_code < 500 and "closure method only" in r.json()["detail"], r.text
