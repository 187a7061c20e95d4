"""Is the calibration still true, from the page: on a device's history a study recording made with its calibration in
force is uploaded and watched; the page says of each scale factor and bias whether it holds or moved (by how much,
when), lists the watch beside the calibration, and the device list says the device is due, and why."""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from webui_fixtures import Watch, Wizard, api, assert_clean, running_service, watched_page

from calib.io.readers import write_native_csv
from calib.simulator.study_day import StudyEvent, simulate_study_day

DEVICE = "ward-7"


@pytest.fixture(scope="module")
def watch_service() -> Iterator[Any]:
    with running_service(["normal"]) as svc:
        yield svc


def test_a_study_recording_watched_from_the_history_page_says_what_moved_and_the_device_is_due(
        browser: Any, watch_service: Any, page_watch: Watch, artifacts: Path, tmp_path: Path) -> None:
    quiet, day = simulate_study_day(6, 900.0)
    dropped, _ = simulate_study_day(6, 900.0, event=StudyEvent(600.0, "b", 2, 0.3))
    files = {"day-1.csv": quiet, "day-2.csv": dropped}
    for name, rec in files.items():
        write_native_csv(rec, tmp_path / name)
    cal = {"k": day.params.k.tolist(), "b": day.params.b.tolist(), "identity": {"temperature_c": day.temp_cal_c}}
    with api(watch_service) as c:
        r = c.post(f"/devices/{DEVICE}/calibrations", content=json.dumps(cal), headers={"Content-Type": "application/json"})
        assert r.status_code == 201, r.text
    with watched_page(browser, watch_service, page_watch) as page:
        w = Wizard(page, watch_service, artifacts / "webui" / "watch")
        w.sign_in()
        page.goto(f"{watch_service.base}/#/history/{DEVICE}")
        for name, verdict in (("day-1.csv", "holds"), ("day-2.csv", "moved")):
            page.wait_for_selector("form.watch")
            page.set_input_files("#watch-file", str(tmp_path / name))
            page.click("form.watch button[type=submit]")
            report = page.wait_for_selector(f".watch-report[data-verdict='{verdict}']", timeout=60_000)
            assert f"{name}: the calibration" in report.inner_text(), report.inner_text()
            if verdict == "moved":
                moved = page.locator(".watch-report li[data-verdict='moved']")
                assert moved.count() == 1 and moved.get_attribute("data-parameter") == "b_z"
                line = moved.inner_text()
                by = re.match(r"b Z moved by \+(\d\.\d{3}) °/s ± \d\.\d{3} °/s, between \d+ s and \d+ s into the recording$", line)
                assert by and abs(float(by.group(1)) - 0.3) < 0.05, line
                assert "calibrate again" in page.inner_text(".watch-verdict")
                w.shot("watch-moved")
            else:
                assert page.locator(".watch-report li[data-verdict='holds']").count() == 6
                assert "°C" in page.inner_text(".watch-evidence") and "left out" in page.inner_text(".watch-evidence")
            page.click("a.reload-history")
            page.wait_for_selector("table.history.watches")
        rows = page.locator("table.history.watches tbody tr")
        assert rows.count() == 2 and rows.nth(0).get_attribute("data-verdict") == "moved"
        assert "b Z moved by" in rows.nth(0).inner_text() and "every one holds" in rows.nth(1).inner_text()
        assert "moved on a study recording: b Z" in page.inner_text("table.calibrations tr.current")
        # k and b against temperature: the lines the two watched days measured, about the calibration's temperature
        charts = page.locator(".plots.temperature figure.plot.temperature")
        assert charts.count() == 2 and page.locator(".plots.temperature path.model").count() == 6
        assert "what 2 watched recordings measured, about calibration #1" in page.inner_text(".plots.temperature")
        page.locator(".plots.temperature").screenshot(path=str(w.shots / "watch-temperature.png"))
        w.shot("watch-history")
        # the device list: due now, and why
        page.goto(f"{watch_service.base}/#/devices")
        note = page.wait_for_selector(f".device-card[data-device='{DEVICE}'] .due-note")
        said = re.search(r"due: a study recording watched today showed b_z moved by \+(\d\.\d{3}) ± \d\.\d{3} deg/s", note.inner_text())
        assert said and abs(float(said.group(1)) - 0.3) < 0.05, note.inner_text()
    assert_clean(page_watch)
