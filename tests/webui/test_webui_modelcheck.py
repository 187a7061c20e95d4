"""The model check panel of the wizard's result details, in Debian's Chromium against the real service.
Screenshots go to artifacts/webui/."""

from __future__ import annotations

import io
from collections.abc import Iterator
from typing import Any

import pytest
from webui_fixtures import Watch, Wizard, api, assert_clean, running_service

from calib.io.readers import write_native_csv
from calib.simulator.concealed import draw_concealed

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def webui_service() -> Iterator[Any]:
    """One simulated wearable doing the protocol, at 20x so that a session takes a few seconds. Its first
    session (seed 1) lies well inside what its simulations produce (the diagnosis's smallest p-value is
    over 20 times its threshold), so the verdict does not hinge on where the session's last rest ended."""
    with running_service(["normal"], "--mock-speed", "20", "--mock-seed", "1") as svc:
        yield svc




def run_model_check(wizard: Wizard, page: Any) -> None:
    page.click("details.details summary")
    panel = page.locator(".modelcheck")
    panel.scroll_into_view_if_needed()
    button = panel.locator("button:has-text('Check the model against simulation')")
    assert button.is_visible()
    button.click()
    # busy: the button gives way to the progress, announced politely
    assert not button.is_visible()
    page.locator(".modelcheck").screenshot(path=str(wizard.shots / "model-check-running.png"))
    page.wait_for_selector(".modelcheck[data-state='done']", timeout=60_000)
    # the finished check is announced in the panel's live region
    assert "Model check finished" in page.inner_text(".modelcheck .mc-status")
    assert page.get_attribute(".modelcheck .mc-status", "aria-live") == "polite"


def check_uploaded(wizard: Wizard, page: Any, webui_service: Any, recording: Any, device: str) -> str:
    """Calibrate ``recording`` as an upload for ``device``, open its session page and run the model check: its id."""
    buf = io.StringIO()
    write_native_csv(recording, buf)
    with api(webui_service) as c:
        r = c.post(f"/devices/{device}/calibrate", content=buf.getvalue(), headers={"Content-Type": "text/csv"})
        assert r.status_code == 200, r.text
        sid = r.json()["session_id"]
    wizard.sign_in()
    page.goto(f"{webui_service.base}/#/session/{sid}")
    page.wait_for_selector(".verdict h1")
    run_model_check(wizard, page)
    return sid


def test_model_check_after_a_session_says_the_recording_looks_like_the_simulation(
        wizard: Wizard, page: Any, webui_service: Any, page_watch: Watch) -> None:
    wizard.sign_in()
    wizard.choose("mock-1")
    sid = wizard.start()
    wizard.wait_state("done", timeout_ms=60_000)
    assert wizard.text(".verdict h1") == "PASS"
    run_model_check(wizard, page)
    panel = page.locator(".modelcheck")
    assert panel.get_attribute("data-verdict") == "clean"
    assert "The recording looks like the simulation" in panel.locator(".mc-verdict.ok").inner_text()
    assert panel.locator(".mc-verdict.ok svg.icon").count() == 1  # colour comes with an icon and words
    with api(webui_service) as c:
        d = c.get(f"/sessions/{sid}/diagnosis").json()
    assert d["effects"] == []
    # what one turn per axis cannot show is said, with its reason
    for n in d["not_identifiable"]:
        assert n["reason"] in panel.inner_text()
    panel.screenshot(path=str(wizard.shots / "model-check-clean.png"))
    wizard.shot("model-check-clean-page")
    assert wizard.small_targets() == []
    assert page.locator(".modelcheck a[href$='/diagnosis/report']").count() == 1
    assert_clean(page_watch)


def test_model_check_names_a_drift_hidden_in_an_uploaded_recording(
        wizard: Wizard, page: Any, webui_service: Any, page_watch: Watch) -> None:
    sid = check_uploaded(wizard, page, webui_service, draw_concealed(2, "bias_drift").recording, "upload-drift")
    panel = page.locator(".modelcheck")
    assert panel.get_attribute("data-verdict") == "effects"
    verdict = panel.locator(".mc-verdict.warn").inner_text()
    assert "Found an effect the calibration model leaves out" in verdict and "drifting zero reading" in verdict
    with api(webui_service) as c:
        d = c.get(f"/sessions/{sid}/diagnosis").json()
    effect = panel.locator(".mc-effect[data-effect='bias_drift']")
    assert "Drifting zero reading" in effect.inner_text()
    assert d["effects"][0]["evidence"]["summary"] in effect.inner_text()
    assert "without it" in effect.inner_text() and "with it" in effect.inner_text()
    rows = panel.locator("table.mc-mismatches tbody tr")
    assert rows.count() == min(8, len(d["mismatches"])) and "°/s" in rows.first.inner_text()
    panel.screenshot(path=str(wizard.shots / "model-check-drift.png"))
    assert wizard.small_targets() == []
    # the full report opens from the panel
    with page.context.expect_page() as popup:
        panel.locator("a:has-text('full report')").click()
    report = popup.value
    report.wait_for_load_state()
    assert "Simulation against reality" in report.inner_text("h1")
    report.close()
    assert_clean(page_watch)


def test_model_check_says_how_a_wander_was_told_from_a_drift(
        wizard: Wizard, page: Any, webui_service: Any, page_watch: Watch) -> None:
    sid = check_uploaded(wizard, page, webui_service, draw_concealed(28, "bias_instability").recording, "upload-wander")
    panel = page.locator(".modelcheck")
    with api(webui_service) as c:
        d = c.get(f"/sessions/{sid}/diagnosis").json()
    assert [e["name"] for e in d["effects"]] == ["bias_instability"]
    (test,) = d["effects"][0]["evidence"]["rivals"]
    rival = panel.locator(".mc-effect[data-effect='bias_instability'] .mc-rival")
    assert rival.count() == 1
    assert "Told apart from drifting zero reading" in rival.inner_text() and test["summary"] in rival.inner_text()
    panel.screenshot(path=str(wizard.shots / "model-check-wander.png"))
    assert_clean(page_watch)
