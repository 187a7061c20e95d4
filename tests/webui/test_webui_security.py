"""The page's browser defences, seen from Chromium: the headers it gets, a policy the page lives with (no
violations), no framing by another site, the API docs from this computer only, and Host names checked."""

from __future__ import annotations

from typing import Any

import httpx
from server_fixtures import RunningService
from webui_fixtures import Watch, Wizard


def test_the_page_carries_its_defences_and_works_under_its_policy(wizard: Wizard, page: Any, webui_service: RunningService,
                                                                  page_watch: Watch) -> None:
    response = page.goto(webui_service.base + "/")
    headers = response.headers
    csp = headers["content-security-policy"]
    for directive in ("default-src 'self'", "script-src 'self'", "frame-ancestors 'none'", "object-src 'none'"):
        assert directive in csp
    assert "unsafe-inline" not in csp and "unsafe-eval" not in csp
    assert headers["x-frame-options"] == "DENY" and headers["x-content-type-options"] == "nosniff"
    assert headers["referrer-policy"] == "no-referrer"
    wizard.sign_in()  # the page signs in and lists devices under that policy
    assert page.query_selector_all(".device-card")
    assert not [e for e in page_watch.console_errors if "Content Security Policy" in e], page_watch.console_errors
    assert not page_watch.blocked


def test_another_site_cannot_frame_the_page(page: Any, webui_service: RunningService) -> None:
    page.set_content(f'<iframe id="f" src="{webui_service.base}/" width="800" height="600"></iframe>')
    page.wait_for_timeout(1500)
    frame = page.frame_locator("#f")
    assert frame.locator("#operator").count() == 0  # the sign-in form never rendered inside the frame


def test_the_api_docs_load_from_this_computer_only(page: Any, webui_service: RunningService, page_watch: Watch) -> None:
    response = page.goto(webui_service.base + "/docs")
    assert response.status == 200
    page.wait_for_selector(".swagger-ui .opblock", timeout=30_000)
    assert page.locator(".opblock-summary-path", has_text="/devices/{device_id}/calibrate").count() >= 1
    assert not page_watch.blocked, page_watch.blocked
    assert all(u.startswith(webui_service.base) or u.startswith(("data:", "blob:")) for u in page_watch.requests)
    assert not [e for e in page_watch.console_errors if "Content Security Policy" in e], page_watch.console_errors


def test_a_forged_host_is_refused(webui_service: RunningService) -> None:
    for host in ("attacker.example", "attacker.example:8000", "127.0.0.1.attacker.example"):
        r = httpx.get(webui_service.base + "/devices", headers={"Host": host}, timeout=10, verify=False)
        assert r.status_code == 400 and "--allowed-host" in r.json()["detail"], (host, r.text)
        assert r.headers["x-frame-options"] == "DENY"
    for host in ("localhost", f"127.0.0.1:{webui_service.port}", f"localhost:{webui_service.port}"):
        assert httpx.get(webui_service.base + "/devices", headers={"Host": host}, timeout=10, verify=False).status_code == 200
