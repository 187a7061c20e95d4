"""Noise from a rest, from the page: a recording of the device lying still is uploaded from the device list's "Noise
from a rest"; the page shows each axis's noise density, bias instability and random walk with its interval (or its
bound), the Allan deviation on log axes, and Kalibr's imu.yaml to download; a recording that turns is named for it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from webui_fixtures import Watch, Wizard, assert_clean, watched_page

from calib.io.readers import write_native_csv
from calib.simulator import simulate
from calib.simulator.rest_noise import RestNoise, simulate_rest


def test_a_rest_uploaded_from_the_page_shows_its_noise_its_allan_curves_and_kalibrs_file(
        browser: Any, webui_service: Any, page_watch: Watch, artifacts: Path, tmp_path: Path) -> None:
    write_native_csv(simulate_rest(9, 1200.0, 100.0, RestNoise(density=0.01, random_walk=3e-4), RestNoise(density=1e-4)),
                     tmp_path / "bench-rest.csv")
    write_native_csv(simulate(4)[0], tmp_path / "turned.csv")
    for phone in (False, True):
        with watched_page(browser, webui_service, page_watch, viewport={"width": 390, "height": 844} if phone else None,
                          phone=phone) as page:
            w = Wizard(page, webui_service, artifacts / "webui" / "noise")
            w.sign_in()
            page.click("#noise-link")
            page.wait_for_selector("#noise-file")
            page.set_input_files("#noise-file", str(tmp_path / "turned.csv"))
            page.click("form.upload-form button[type=submit]")
            page.locator(".scan-note", has_text="turns").wait_for(timeout=30_000)
            assert "one rest" in page.inner_text(".scan-note")
            page.set_input_files("#noise-file", str(tmp_path / "bench-rest.csv"))
            page.click("form.upload-form button[type=submit]")
            page.wait_for_selector(".noise-table.gyro tbody tr", timeout=60_000)
            rows = page.locator(".noise-table.gyro tbody tr")
            assert rows.count() == 3 and page.locator(".noise-table.accel tbody tr").count() == 3
            x = rows.nth(0).locator("td").nth(0).inner_text()
            assert "°/√h" in x and "(" in x and "τ 0.04 s" in x, x  # 0.6 °/√h = 0.01 (deg/s)/√Hz, with its interval
            assert abs(float(x.split()[0]) - 0.6) < 0.02, x
            charts = page.locator(".noise-result figure.plot")
            assert charts.count() == 2 and page.locator(".noise-result path.series.measured").count() == 6
            assert page.locator(".noise-result path.series.fitted").count() == 6
            assert "1200 s at 100 Hz" in page.inner_text(".noise-result .outcome")
            with page.expect_download() as dl:
                page.click("#kalibr-download")
            kalibr = yaml.safe_load(Path(dl.value.path()).read_text())
            assert abs(kalibr["gyroscope_noise_density"] / (0.01 * 3.14159265 / 180) - 1) < 0.03 and kalibr["update_rate"] == 100
            w.shot("noise-phone" if phone else "noise")
            assert w.small_targets() == []
    assert_clean(page_watch, allowed_errors=("400 (Bad Request)",))  # the turned recording, refused on purpose
