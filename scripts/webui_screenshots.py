"""Screenshots of every state of the clinician's page, for docs/webui.md.

Starts `gyrocal serve` with simulated wearables on a fresh store, drives Chromium through each state with
Playwright at a landscape (1280x800) and a portrait (820x1180) tablet and a phone (390x844, a phone's browser), and
writes docs/img/webui/<state>-<view>.jpg. Then a second service mounts four simulated wearables in one tray (the
fourth settles in its slot in the pause after the turn about Y) for the kit's page, kit-<state>-<view>.jpg.

    .venv/bin/python scripts/webui_screenshots.py [--out docs/img/webui]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = "/usr/lib/chromium/chromium-headless-shell"  # as the page tests: scripts/install-system-deps.sh
OPERATOR, SECRET, PIN = "alice", "correct horse battery staple", "4831"
TOKEN = "screenshots-token"
VIEWS = {"landscape": {"width": 1280, "height": 800}, "portrait": {"width": 820, "height": 1180},
         "phone": {"width": 390, "height": 844}}
# mock-N performs SCENARIOS[N-1]; the careful hand follows the page's prompts
SCENARIOS = ["hand:careful", "hand:careful", "wrong_axis", "moved_during_still", "link_drop", "hand:careful", "hand:bumps",
             "hand:short"]
# one tray of four prompt-following hands; each view calibrates three of them (the one left out differs per view, the
# loose fourth is in every kit), so no view finds its wearables holding a result another view left unsaved
KIT = ["--mock", "4", "--mock-kit", "--mock-kit-loose", "4", "--mock-kit-loose-in", "pause", "--mock-scenario",
       ",".join(["hand:careful"] * 4)]


@contextlib.contextmanager
def service(mocks: list[str]) -> Iterator[str]:
    """`gyrocal serve` on a free port with the simulated wearables ``mocks`` (its --mock options) and an operator with
    a secret and a PIN."""
    tmp = Path(tempfile.mkdtemp(prefix="gyrocal-shots-"))
    db = f"sqlite:///{tmp / 'store.sqlite3'}"
    gyrocal = [sys.executable, "-m", "calib.cli.main"]
    subprocess.run([*gyrocal, "operator", "--db", db, "add", OPERATOR, "--secret-stdin"], input=SECRET + "\n", check=True,
                   cwd=ROOT, capture_output=True, text=True)
    subprocess.run([*gyrocal, "operator", "--db", db, "pin", OPERATOR, "--pin-stdin"], input=PIN + "\n", check=True,
                   cwd=ROOT, capture_output=True, text=True)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {**os.environ, "GYROCAL_API_TOKEN": TOKEN}
    proc = subprocess.Popen([*gyrocal, "serve", "--port", str(port), "--db", db, "--log-level", "warning", "--mock-speed", "1",
                             *mocks], cwd=ROOT, env=env)
    base = f"http://127.0.0.1:{port}"
    try:
        for _ in range(300):
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(base + "/health", timeout=1).status_code == 200:
                    break
            time.sleep(0.1)
        yield base
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=20)
        shutil.rmtree(tmp, ignore_errors=True)


class Shots:
    """One browser page per view; ``take`` saves the page as <state>-<view>.jpg."""

    def __init__(self, browser: Any, base: str, out: Path, view: str) -> None:
        self.base, self.out, self.view = base, out, view
        phone = {"is_mobile": True, "device_scale_factor": 2} if view == "phone" else {}
        self.ctx = browser.new_context(viewport=VIEWS[view], has_touch=True, base_url=base, locale="en-GB", timezone_id="Europe/Vienna",
                                       **phone)
        self.page = self.ctx.new_page()
        self.page.set_default_timeout(60_000)

    def take(self, state: str, full: bool = False) -> None:
        self.page.screenshot(path=str(self.out / f"{state}-{self.view}.jpg"), full_page=full, type="jpeg", quality=80)
        print(f"  {state}-{self.view}.jpg")

    def sign_in(self) -> None:
        self.page.goto(self.base + "/")
        self.page.wait_for_selector("#operator")

    def sign_in_with_pin(self, shot: bool = False) -> None:
        """Sign in as the operator with the PIN (``shot``: the filled form taken as sign-in), to the device list."""
        self.sign_in()
        self.page.click("button.mode-pin")
        self.page.fill("#operator", OPERATOR)
        self.page.fill("#pin", PIN)
        if shot:
            self.take("sign-in")
        self.page.click("form.signin button[type=submit]")
        self.wait(".device-card")

    def session_of(self, device: str) -> None:
        self.page.goto(f"{self.base}/#/place/{device}")
        with contextlib.suppress(Exception):  # leaving a PASS nobody saved asks first: leave it unsaved
            self.page.click("dialog.ask button:has-text('Leave without saving')", timeout=1500)
        self.page.click(".wizard[data-state='place'] button.primary:not([disabled])")
        self.page.wait_for_url(re.compile(r"#/session/[0-9a-f]{32}$"))

    def wait(self, selector: str) -> None:
        self.page.wait_for_selector(selector)


def walk(sh: Shots, nth: int) -> None:
    """Every state, in the order a clinician meets them; ``nth`` picks this view's own wearables."""
    p = sh.page
    sh.sign_in_with_pin(shot=True)
    sh.take("devices")
    careful = ["mock-1", "mock-2"][nth] if nth < 2 else "mock-6"
    p.click(f".device-card[data-device='{careful}'] a.button.primary")
    sh.wait(".wizard[data-state='place'] button.primary:not([disabled])")
    sh.take("place")
    p.click(".wizard[data-state='place'] button.primary")
    sh.wait(".wizard[data-state='still'] .ring-wrap")
    time.sleep(0.6)
    sh.take("hold-still")
    sh.wait(".wizard[data-state='turn_x'][data-phase='ready']")
    sh.take("turn-ready")
    sh.wait(".wizard[data-state='turn_x'][data-phase='turning']")
    time.sleep(0.5)
    sh.take("turning")
    sh.wait(".wizard[data-state='turn_x'][data-phase='placing']")
    sh.take("stopping")
    sh.wait(".wizard[data-state='turn_x'][data-phase='checking']")
    sh.take("checking-turn")
    sh.wait(".wizard[data-state='turn_x'][data-phase='pause']")
    time.sleep(0.3)
    sh.take("pause")
    sh.wait(".verdict h1")
    sh.take("pass")
    p.click("details.details summary")
    sh.wait(".plots figure")
    p.query_selector("details.details").scroll_into_view_if_needed()
    sh.take("details", full=True)
    p.click("button.accept")
    sh.wait(".verdict.saved")
    sh.take("saved")
    # a device with an accepted calibration: the gauge in true degrees
    p.goto(f"{sh.base}/#/place/{careful}")
    p.click(".wizard[data-state='place'] button.primary:not([disabled])")
    sh.wait(".wizard[data-state='turn_y'][data-phase='turning'] .gauge-wrap:not(.no-target)")
    time.sleep(0.6)
    sh.take("turning-with-target")
    sh.wait(".verdict h1")
    p.click("button:has-text('Discard')")
    sh.wait(".verdict.neutral")
    sh.take("discarded")
    p.goto(f"{sh.base}/#/history/{careful}")
    sh.wait("table.calibrations")
    sh.take("history", full=True)


def faults(sh: Shots, nth: int) -> None:
    """The warnings and the ways a session stops, once (landscape only)."""
    sh.page.goto(f"{sh.base}/#/devices")
    sh.wait(".device-card[data-device='mock-8'] button.identify")
    sh.page.click(".device-card[data-device='mock-8'] button.identify")
    sh.wait(".device-card[data-device='mock-8'] .identify-status.ok")
    sh.page.query_selector(".device-card[data-device='mock-8']").scroll_into_view_if_needed()
    sh.take("identify")
    # stops its first z turn short: the result asks that turn again (this service gives one try per turn; this
    # session three, as the service's default does)
    started = httpx.post(f"{sh.base}/devices/mock-8/calibrate", json={"max_attempts": 3},
                         headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30).json()
    sh.page.goto(f"{sh.base}/#/session/{started['session_id']}")
    sh.page.wait_for_function("""() => { const n = document.querySelector(".wizard[data-state='turn_z'] .notice.warn");
      return n && n.textContent.includes("Attempt 2"); }""", polling=20, timeout=90_000)
    sh.take("turn-asked-again")
    sh.wait(".verdict h1")
    sh.session_of("mock-7")  # a hand that knocks the device in one of the pauses
    sh.wait(".notice.warn")
    sh.take("moved-warning")
    sh.wait(".verdict h1")
    sh.session_of("mock-3")
    sh.wait(".verdict h1")
    sh.take("stopped-wrong-axis")
    sh.session_of("mock-4")
    sh.wait(".verdict h1")
    sh.take("stopped-moved-in-a-pause")
    sh.session_of("mock-5")
    sh.wait(".wizard[data-state='reconnecting']")
    sh.take("connection-lost")
    sh.wait(".verdict h1, .wizard[data-state='still'], .wizard[data-state^='turn_']")
    sh.page.click("button.cancel")
    sh.wait(".verdict.neutral")
    sh.take("cancelled")
    del nth


def kit(sh: Shots, nth: int) -> None:
    """The kit's page: three wearables chosen, the tray held still and turned, the loose one named in its row while
    the tray goes on, the result, saved."""
    p = sh.page
    sh.sign_in_with_pin()
    for device in [d for d in ("mock-1", "mock-2", "mock-3") if d != f"mock-{nth + 1}"] + ["mock-4"]:
        p.check(f".device-card[data-device='{device}'] .kit-pick input")
    p.locator("#kit-start").scroll_into_view_if_needed()
    sh.take("kit-chosen")
    p.click("#kit-start")
    sh.wait(".kit[data-state='still'] .kit-cue .ring-wrap")
    time.sleep(1.0)
    sh.take("kit-hold-still")
    sh.wait(".kit[data-state='turn_x'] .kit-cue .gauge-wrap")
    time.sleep(1.0)
    sh.take("kit-turning")
    sh.wait(".kit-device[data-device='mock-4'] .kit-moved")
    # (by querySelector: the kit redraws a row whose words change, and a located row may be gone by the scroll)
    p.evaluate("""() => { const row = document.querySelector(".kit-device[data-device='mock-4']");
      if (row) row.scrollIntoView({ block: 'center' }); }""")
    sh.take("kit-moved-in-its-slot")
    p.wait_for_selector(".kit[data-state='done']", timeout=120_000)
    sh.take("kit-result", full=True)
    if p.locator("#kit-accept").count() == 0:
        raise SystemExit(f"the kit ended without a wearable to accept: {p.inner_text('.kit')}")
    p.click("#kit-accept")
    sh.wait("#kit-saved")
    p.locator("#kit-saved").scroll_into_view_if_needed()
    sh.take("kit-saved")


STEPS: dict[str, Callable[[Shots, int], None]] = {"walk": walk, "faults": faults, "kit": kit}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img" / "webui")
    ap.add_argument("--steps", type=lambda v: set(v.split(",")), default=set(STEPS),
                    help=f"which walks, comma-separated, of {', '.join(STEPS)} (default: all)")
    args = ap.parse_args(argv)
    if unknown := args.steps - set(STEPS):
        ap.error(f"--steps: no walk named {', '.join(sorted(unknown))}; choose from {', '.join(STEPS)}")
    args.out.mkdir(parents=True, exist_ok=True)
    from playwright.sync_api import sync_playwright

    wearables = ["--mock", str(len(SCENARIOS)), "--mock-scenario", ",".join(SCENARIOS), "--max-attempts", "1"]
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=["--no-sandbox"])
        for mocks, steps in ((wearables, args.steps - {"kit"}), (KIT, args.steps & {"kit"})):
            if not steps:
                continue
            with service(mocks) as base:
                for nth, view in enumerate(VIEWS):
                    print(view)
                    sh = Shots(browser, base, args.out, view)
                    for step in sorted(steps, key=list(STEPS).index):
                        if step == "faults" and view != "landscape":
                            continue
                        STEPS[step](sh, nth)
                    sh.ctx.close()
        browser.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
