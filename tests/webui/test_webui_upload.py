"""Calibrating a recording file from the page, in Debian's Chromium against the real service: imucal's labelled
raw-counts session is read with its sensitivities, recognised as Ferraris' protocol and shown as a session."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
from webui_fixtures import Watch, Wizard, api, assert_clean

pytestmark = pytest.mark.timeout(120)


def test_an_uploaded_counts_file_is_recognised_and_its_result_shown(wizard: Wizard, page: Any, webui_service: Any,
                                                                    page_watch: Watch, real_data: Path) -> None:
    wizard.sign_in()
    page.click("#upload-link")
    page.wait_for_selector("form.upload-form")
    page.fill("#up-device", "imucal-annotated")
    page.set_input_files("#up-file", str(real_data / "imucal" / "annotated_session.csv"))
    page.fill("#up-fs", "204.8")
    page.click("form.upload-form button[type=submit]")
    # raw counts without their sensitivities: the service's reason is shown, nothing is stored
    page.wait_for_selector("form.upload-form [role=status]:has-text('gyro_counts_per_dps')")
    with api(webui_service) as c:
        assert c.get("/devices/imucal-annotated").status_code == 404
    page.fill("#up-gyro-counts", "16.4")
    page.fill("#up-accel-counts", "2048")
    page.select_option("#up-protocol", "ferraris")
    wizard.shot("upload-form")
    page.click("form.upload-form button[type=submit]")
    page.wait_for_url("**/#/session/*")
    page.wait_for_selector(".verdict h1")
    page.click("details.details summary")
    facts = page.locator("dl.facts").inner_text()
    assert "Ferraris' protocol: the six static poses" in facts and "used: ferraris" in facts
    assert "0.9833" in page.locator("table.params").inner_text()  # k_x: imucal's 16.4 / 16.6777 = 0.98334
    wizard.shot("upload-result")
    assert wizard.small_targets() == []
    assert_clean(page_watch, allowed_errors=("status of 400",))  # the refused first try, and only that
    assert sum("status of 400" in e for e in page_watch.console_errors) == 1


def test_a_multi_position_upload_shows_the_g_sensitivity_it_found(wizard: Wizard, page: Any, page_watch: Watch,
                                                                  tmp_path: Path) -> None:
    import numpy as np

    from calib.effects.axes import GSensitivity
    from calib.io.readers import write_native_csv
    from calib.simulator import simulate
    from calib.simulator.lab_scripts import multi_position_script

    G = 1.5 * np.array([[0.02, -0.06, 0.03], [0.08, 0.01, -0.04], [-0.05, 0.07, 0.02]])  # (deg/s)/g, concealed
    rec, _ = simulate(5, noise=0.05, fs=100.0, script=multi_position_script(np.random.default_rng(5), n=12, first_rest_s=20.0),
                      accel_noise_g=0.005, effects=[GSensitivity(G)])
    path = tmp_path / "re-orientations.csv"
    write_native_csv(rec, path)
    wizard.sign_in()
    page.click("#upload-link")
    page.wait_for_selector("form.upload-form")
    page.fill("#up-device", "re-oriented")
    page.set_input_files("#up-file", str(path))
    page.click("form.upload-form button[type=submit]")
    page.wait_for_url("**/#/session/*")
    page.wait_for_selector(".verdict h1")
    page.click("details.details summary")
    facts = page.locator("dl.facts").inner_text()
    assert "used: multi-position" in facts
    assert "found and modelled (significant" in facts
    largest = float(re.search(r"up to ([0-9.]+) \(°/s\)/g", facts).group(1))  # type: ignore[union-attr]
    assert abs(largest - 0.12) < 0.01  # the concealed G's largest entry
    assert "without it the gravity residuals were 0.26° rms" in facts and "0.03° rms over 12 motions" in facts
    wizard.shot("upload-g-sensitivity")
    assert_clean(page_watch)


def test_imu_tk_s_two_files_are_uploaded_from_the_page(wizard: Wizard, page: Any, page_watch: Watch, real_data: Path) -> None:
    """imu_tk's Xsens session, its gyroscope and accelerometer files chosen on the form: calibrated from its 37
    re-orientations and shown, with why it cannot be accepted (imu_tk's example sensitivities read it 31 % low)."""
    wizard.sign_in()
    page.click("#upload-link")
    page.wait_for_selector("form.upload-form")
    page.fill("#up-device", "xsens-imu-tk")
    page.set_input_files("#up-file", str(real_data / "imu_tk" / "xsens_gyro.mat"))
    page.set_input_files("#up-accel-file", str(real_data / "imu_tk" / "xsens_acc.mat"))
    page.click("form.upload-form button[type=submit]")
    page.wait_for_url("**/#/session/*", timeout=60_000)
    page.wait_for_selector(".verdict h1")
    assert "k_x = 1.3087 (allowed 0.8 to 1.2)" in page.inner_text("main")
    page.click("details.details summary")
    facts = page.locator("dl.facts").inner_text()
    assert "used: multi-position" in facts and "over 37 motions" in facts
    assert "1.30869 ± 0.00031" in page.locator("table.params").inner_text()
    wizard.shot("upload-imu-tk")
    assert_clean(page_watch)
