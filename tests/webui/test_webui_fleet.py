"""The fleet page in a real browser: two gateway processes on one PostgreSQL; the page of one lists both rooms'
wearables, updates live when the other room starts a session, follows that session live from its own gateway
(through the database's notifications), accepts its result there, and links to the wizard on the gateway that
holds each wearable."""

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
        sid = r.json()["session_id"]
        page.wait_for_selector(".fleet-table tr[data-device='mock-3'] td.fleet-status.busy", timeout=15_000)
        page.wait_for_selector(".fleet-table tr[data-device='mock-3'] a:has-text('Follow')", timeout=15_000)
        links = page.query_selector_all(".fleet-table tr[data-device='mock-3'] a")
        assert [(a.inner_text().strip(), a.get_attribute("href")) for a in links] == [
            ("Follow", f"#/session/{sid}"), ("Open on room-b", f"{b.base}/#/place/mock-3")]
        assert "In a calibration" in page.inner_text(".fleet-table tr[data-device='mock-3']")
        wizard.shot("fleet")
        assert wizard.small_targets() == []

        # room-a's page follows room-b's session live: its steps, then its result, which room-a can accept
        links[0].click()
        page.wait_for_selector(".remote-note:has-text('room-b')")
        assert page.get_attribute(".wiz-head a.remote", "href") == f"{b.base}/#/session/{sid}"
        assert page.locator(".wiz-head button.cancel").count() == 0  # cancelled where the wearable is
        wizard.wait_state("turn_x", "turn_y", "turn_z", timeout_ms=60_000)
        wizard.shot("followed-from-another-gateway")
        page.wait_for_selector("button.accept", timeout=90_000)
        page.click("button.accept")
        page.wait_for_selector(".wizard[data-decision='accepted']")
        with api(b) as c:
            assert c.get(f"/sessions/{sid}").json()["decision"] == "accepted"
        page.goto(f"{a.base}/#/fleet")
        page.wait_for_selector(".fleet-table tr[data-device='mock-3'] td.fleet-status.free", timeout=15_000)
        assert "Current" in page.inner_text(".fleet-table tr[data-device='mock-3'] td.fleet-cal")
    assert_clean(page_watch)
