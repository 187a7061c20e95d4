"""Calibrating a recording file from the page, in Debian's Chromium against the real service: imucal's labelled
raw-counts session is read with its sensitivities, recognised as Ferraris' protocol and shown as a session."""

from __future__ import annotations

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
