"""The fleet page in a real browser: two gateway processes on one PostgreSQL; the page of one lists both rooms'
wearables, updates live when the other room starts a session, and links to the wizard on the gateway that holds
each wearable."""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from server_fixtures import GYROCAL, ROOT, RunningService
from webui_fixtures import OPERATOR, SECRET, Watch, Wizard, api, assert_clean, watched_page


@pytest.fixture
def two_rooms(postgres) -> Iterator[tuple[RunningService, RunningService]]:  # noqa: F811
    owner = postgres.create_database()
    url = postgres.service_url(owner)
    add = subprocess.run([*GYROCAL, "operator", "--db", url, "add", OPERATOR, "--secret-stdin"], input=SECRET + "\n",
                         check=False, cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert add.returncode == 0, add.stderr
    rooms = [RunningService(["--gateway", name, "--mock", "2", "--mock-first", str(first), "--mock-speed", "3"], url)
             for name, first in (("room-a", 1), ("room-b", 2))]
    for svc in rooms:
        svc.start(60)
    try:
        yield rooms[0], rooms[1]
    finally:
        for svc in rooms:
            svc.stop()


def test_the_fleet_page_shows_both_rooms_live_and_links_to_the_gateway_that_holds_a_wearable(
        browser: Any, two_rooms: tuple[RunningService, RunningService], artifacts: Path, page_watch: Watch) -> None:
    a, b = two_rooms
    with watched_page(browser, a, page_watch) as page:
        wizard = Wizard(page, a, artifacts / "webui" / "fleet")
        wizard.sign_in()
        page.click("#fleet-link")
        page.wait_for_selector(".fleet-table tr[data-device='mock-3']")
        assert [g.get_attribute("data-gateway") for g in page.query_selector_all(".gateway.alive")] == ["room-a", "room-b"]
        rows = {r.get_attribute("data-device"): r for r in page.query_selector_all(".fleet-table tbody tr")}
        assert sorted(rows) == ["mock-1", "mock-2", "mock-3"]
        assert "seen by 2" in rows["mock-2"].inner_text()  # both rooms see mock-2
        assert rows["mock-3"].query_selector("a").get_attribute("href") == f"{b.base}/#/place/mock-3"
        assert rows["mock-1"].query_selector("a").get_attribute("href") == "#/place/mock-1"
        assert all("Never calibrated" in r.inner_text() for r in rows.values())

        with api(b) as c:  # room-b starts a session; room-a's page shows it without a reload
            r = c.post("/devices/mock-3/calibrate", json={})
            assert r.status_code == 202, r.text
        page.wait_for_selector(".fleet-table tr[data-device='mock-3'] td.fleet-status.busy", timeout=15_000)
        link = page.query_selector(".fleet-table tr[data-device='mock-3'] a")
        assert link.inner_text().strip() == "Follow on room-b" and link.get_attribute("href") == f"{b.base}/#/place/mock-3"
        wizard.shot("fleet")
        assert wizard.small_targets() == []
        with api(b) as c:
            assert c.post(f"/sessions/{r.json()['session_id']}/cancel").status_code == 200
        page.wait_for_selector(".fleet-table tr[data-device='mock-3'] td.fleet-status.free", timeout=15_000)
    assert_clean(page_watch)
