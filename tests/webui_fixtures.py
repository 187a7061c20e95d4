"""Fixtures of the wizard page tests: the real service with simulated wearables, Debian's Chromium
driven by Playwright, and a page that refuses every request leaving this computer.

Registered as a plugin by tests/conftest.py: the fixtures need no import; the helpers are imported by name.
"""

from __future__ import annotations

import contextlib
import functools
import io
import json
import re
import shutil
import subprocess
import tempfile
from collections.abc import Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import httpx
import pytest
from server_fixtures import GYROCAL, ROOT, RunningService

# Debian's headless shell: Chromium's renderer (Blink) without the whole browser around it (its own interface is web
# pages too), the headless Chromium Playwright drives by default. The whole browser took half as much CPU again (the
# page tests on two workers: 506 s of CPU in 330 s, against 340 s in 267 s): CPU the service and the hands beside it need
CHROMIUM = Path("/usr/lib/chromium/chromium-headless-shell")
CHROMIUM_ARGS = ["--no-sandbox", "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run"]
OPERATOR = "alice"
SECRET = "correct horse battery staple"
MOCK_SPEED = 3.0  # the prompt-following clinicians react to the page's prompts: their lag is in device time
SCRIPTED_SPEED = 6.0  # the scripted clinicians play a fixed script, whatever the page shows
# the simulated clinician of mock-N performs the N-th scenario in every session
SCENARIOS = ["normal", "moved_during_still", "wrong_axis", "link_drop", *["normal"] * 9]
PIN = "4831"
# clinicians who follow the page's prompts (mock_device.hand), each on a wearable of its own
HAND_SCENARIOS = ["hand:careful", "hand:careful", "hand:gauge", "hand:careful"]
TABLET = {"width": 1024, "height": 768}
VIEWS = {"1280x800": {"width": 1280, "height": 800}, "820x1180": {"width": 820, "height": 1180}, "390x844": {"width": 390, "height": 844}}
PHONE_VIEW = "390x844"  # a phone's browser: touch only, at its pixel density
WRONG_PIN = ("401 (Unauthorized)",)  # the console's line for the wrong PIN a test types on purpose
LOCAL_HOSTS = {"127.0.0.1", "localhost", "[::1]", "::1"}


def device_for(scenario: str, nth: int = 1) -> str:
    """The id of the nth simulated wearable that performs a scenario."""
    ids = [f"mock-{i + 1}" for i, s in enumerate(SCENARIOS) if s == scenario]
    return ids[nth - 1]


@contextlib.contextmanager
def running_service(scenarios: list[str], *extra: str, speed: float = MOCK_SPEED) -> Iterator[RunningService]:
    """`gyrocal serve` with one simulated wearable per scenario (at ``speed`` times real time) and an operator, on a
    fresh SQLite store."""
    tmp = Path(tempfile.mkdtemp(prefix="gyrocal-webui-"))
    db = f"sqlite:///{tmp / 'store.sqlite3'}"
    add = subprocess.run([*GYROCAL, "operator", "--db", db, "add", OPERATOR, "--secret-stdin"], input=SECRET + "\n", check=False,
                         cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert add.returncode == 0, add.stderr
    svc = RunningService(
        ["--mock", str(len(scenarios)), "--mock-speed", str(speed), "--mock-scenario", ",".join(scenarios), *extra], db
    )
    svc.start()
    try:
        yield svc
    finally:
        svc.stop()
        shutil.rmtree(tmp, ignore_errors=True)


@pytest.fixture(scope="module")
def webui_service() -> Iterator[RunningService]:
    """The service the page tests run against: mock-N performs SCENARIOS[N-1], one try per turn (the scripted
    clinicians play a fixed script and never turn again, so each fault ends its session with its own screen)."""
    with running_service(SCENARIOS, "--max-attempts", "1", speed=SCRIPTED_SPEED) as svc:
        yield svc


@pytest.fixture(scope="module")
def hand_service() -> Iterator[RunningService]:
    """A service whose simulated clinicians follow the session's prompts, read from the service as the page reads
    them (mock-N performs HAND_SCENARIOS[N-1]); the operator also has a PIN."""
    with running_service(HAND_SCENARIOS) as svc:
        give_the_operator_a_pin(svc)
        yield svc


def give_the_operator_a_pin(svc: RunningService) -> None:
    """The operator may also sign in with ``PIN`` (as a clinician at a shared tablet does)."""
    r = subprocess.run([*GYROCAL, "operator", "--db", svc.db_url, "pin", OPERATOR, "--pin-stdin"], input=PIN + "\n", check=False,
                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr


@pytest.fixture(scope="module")
def metawear_service() -> Iterator[RunningService]:
    """A service whose one simulated wearable speaks MbientLab's MetaWear protocol."""
    with running_service(["normal"], "--mock-model", "metawear") as svc:
        yield svc


@pytest.fixture(scope="module")
def dot_service() -> Iterator[RunningService]:
    """A service whose one simulated wearable is a Movella DOT."""
    with running_service(["normal"], "--mock-model", "movella-dot") as svc:
        yield svc


@pytest.fixture(scope="module")
def retry_service() -> Iterator[RunningService]:
    """A service that asks for a turn again after a fault (two tries per turn); mock-1 is bumped in a pause, mock-2
    turns too fast."""
    with running_service(["moved_during_still", "too_fast"], "--max-attempts", "2") as svc:
        yield svc


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    """Debian's Chromium headless shell (Playwright drives it; no browser is downloaded)."""
    if not CHROMIUM.is_file():
        pytest.fail(
            "Chromium's headless shell is not installed: run `make test` (it runs scripts/install-system-deps.sh) or "
            "`sudo apt-get install chromium-headless-shell`"
        )
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


@dataclass
class Watch:
    """What a page did that a test must check: requests, blocked requests, console errors."""

    requests: list[str] = field(default_factory=list)
    blocked: list[str] = field(default_factory=list)
    console_errors: list[str] = field(default_factory=list)


def _is_local(url: str) -> bool:
    parts = urlsplit(url)
    if parts.scheme in ("data", "blob", "about"):
        return True
    return (parts.hostname or "") in LOCAL_HOSTS


@pytest.fixture
def page_watch() -> Watch:
    return Watch()


@contextlib.contextmanager
def watched_page(browser: Any, service: RunningService, watch: Watch, viewport: dict[str, int] | None = None,
                 timeout_ms: float = 30_000, phone: bool = False) -> Iterator[Any]:
    """A fresh page on ``service`` (tablet-sized unless ``viewport``; ``phone``: a phone's browser, touch only, at its
    pixel density); requests to anywhere but this computer are refused, and every request, refusal and console error
    goes to ``watch``."""
    mobile = {"is_mobile": True, "device_scale_factor": 3} if phone else {}
    context = browser.new_context(viewport=viewport or TABLET, has_touch=True, base_url=service.base, locale="en-GB",
                                  timezone_id="Europe/Vienna", **mobile)

    def refuse(route: Any) -> None:
        watch.blocked.append(route.request.url)
        route.abort()

    context.route(lambda url: not _is_local(url), refuse)
    context.on("request", lambda req: watch.requests.append(req.url))
    pg = context.new_page()
    pg.set_default_timeout(timeout_ms)
    pg.on("console", lambda msg: watch.console_errors.append(msg.text) if msg.type == "error" else None)
    pg.on("pageerror", lambda exc: watch.console_errors.append(f"uncaught: {exc}"))
    try:
        yield pg
    finally:
        context.close()


@pytest.fixture
def page(browser: Any, webui_service: RunningService, page_watch: Watch) -> Iterator[Any]:
    """A fresh tablet-sized page on the service; requests to anywhere but this computer are refused."""
    with watched_page(browser, webui_service, page_watch) as pg:
        yield pg


@pytest.fixture
def wizard(page: Any, webui_service: RunningService, artifacts: Path, request: pytest.FixtureRequest) -> Wizard:
    """The wizard page driven like a clinician; screenshots go to artifacts/webui/<test>."""
    return Wizard(page, webui_service, artifacts / "webui" / request.node.name)


# The device time of the session's event the page is handling or last handled (``window.lastEvent``), for the
# recorder's samples: what the page shows is read against the device's time it was said at, not the page's own clock,
# which a busy machine holds back and then lets run through a burst of events
LAST_EVENT = """(() => {
  const Native = window.EventSource;
  window.lastEvent = null;
  window.EventSource = class extends Native {
    addEventListener(type, fn, options) {
      super.addEventListener(type, (ev) => {
        try {
          const s = JSON.parse(ev.data);
          if (s && s.live && typeof s.live.t_device_s === 'number') window.lastEvent = { t: s.live.t_device_s };
        } catch { /* not a snapshot */ }
        fn(ev);
      }, options);
    }
  };
})()"""


class Wizard:
    """Drives the wizard page like a clinician, and saves a screenshot of each step."""

    def __init__(self, page: Any, service: RunningService, shots: Path) -> None:
        self.page = page
        self.service = service
        self.shots = shots
        shots.mkdir(parents=True, exist_ok=True)
        page.add_init_script(LAST_EVENT)

    def shot(self, name: str) -> Path:
        """A screenshot of the screen as it is, which must also pass axe-core's accessibility rules."""
        path = self.shots / f"{name}.png"
        self.page.screenshot(path=str(path))
        assert_accessible(self.page, name)
        return path

    def sign_in(self, shot: str | None = None) -> None:
        self.page.goto(self.service.base + "/")
        self.page.wait_for_selector("#operator")
        self.page.fill("#operator", OPERATOR)
        self.page.fill("#secret", SECRET)
        if shot:
            self.shot(shot)
        self.page.click("form.signin button[type=submit]")
        self.page.wait_for_selector(".device-card")

    def choose(self, device: str) -> None:
        self.page.click(f".device-card[data-device='{device}'] a.button.primary")
        self.page.wait_for_selector(".wizard[data-state='place'] button.primary:not([disabled])")

    def start(self) -> str:
        """Press Start; returns the new session's id (from the page's address)."""
        self.page.click(".wizard[data-state='place'] button.primary")
        self.page.wait_for_url(re.compile(r"#/session/[0-9a-f]{32}$"))
        return self.page.url.rsplit("/", 1)[1]

    def wait_state(self, *states: str, phase: str | None = None, timeout_ms: float = 30_000) -> str:
        """Wait until the page shows one of the session states (and phase); returns the state."""
        sel = ", ".join(f".wizard[data-state='{s}']" + (f"[data-phase='{phase}']" if phase else "") for s in states)
        el = self.page.wait_for_selector(sel, timeout=timeout_ms)
        return el.get_attribute("data-state")

    def text(self, selector: str) -> str:
        return self.page.inner_text(selector).strip()

    def record(self) -> None:
        """Start recording, in the page, what passes too quickly to wait for: the largest angle the gauge
        showed in each turn (turning, or the device being put down) and its target, every text the gauge showed,
        every headline and every state:phase in order (taken at each change of the page, so none that lasts a single
        event is missed), whether the
        stillness ring showed the device moving, every notice, the notice beside each state:phase
        ("turn_x:ready|<notice>"), the turns shown done after each change ("xy"), in ``samples`` the moments (every
        100 ms and every change: time, state:phase, notice box, headline, time-left line, ring percent, the device time
        of the event last handled), whether the gauge was ever
        gone while the device was being put down (placing), and in ``shown`` what each screen said as it changed
        (state:phase, headline, the line under it, the recorded-turn line and the notices with their classes), so that
        a test on a busy machine waits only for the end and reads back what passed on the way."""
        self.page.evaluate("""() => {
          window.lastEvent = null;  // an earlier session's, on this page: the device time of this one's comes with its events
          window.seen = { gauge: {}, gaugeText: {}, targets: {}, headlines: [], phases: [], ringMoving: false, notices: [],
                          phaseNotices: [], done: [], placingWithoutGauge: false, screens: {}, shown: [], samples: [],
                          gaugeWidth: {}, again: [] };
          const last = (list) => list[list.length - 1];
          const text = (sel) => { const el = document.querySelector(sel); return el ? el.textContent.trim() : ''; };
          // the moments: every 100 ms and at every change, [ms, state:phase, notice box, headline, time-left line, the
          // stillness ring's percent (null: no ring)]
          const sample = () => {
            const w = document.querySelector('.wizard'), limit = document.querySelector('.time-left');
            const ring = document.querySelector('.ring-wrap');
            window.seen.samples.push([Math.round(performance.now()), w ? `${w.dataset.state}:${w.dataset.phase || ''}` : '',
                                      text('.notice-box'), text('.instruction'), limit && !limit.hidden ? limit.textContent : '',
                                      ring ? Number(ring.getAttribute('aria-valuenow')) : null,
                                      window.lastEvent ? window.lastEvent.t : null]);
          };
          setInterval(sample, 100);
          // while a session runs and on its result: what she must press, reach or watch (Cancel, the ring or gauge, the turn
          // tiles, the result's main button) that ends
          // below the first screen, as "state:phase: selector ends at y", each once
          window.seen.offScreen = [];
          const offScreen = () => {
            const w = document.querySelector('.wizard.live');
            if (!w || !w.dataset.state || ['place', 'connecting', 'computing'].includes(w.dataset.state)) return;
            for (const sel of ['.wiz-head button.cancel', '.ring-wrap', '.gauge-wrap', '.tiles', '.wizard .actions .button.primary']) {
              const el = document.querySelector(sel);
              if (!el || el.closest('[hidden]')) continue;
              const r = el.getBoundingClientRect();
              if (r.bottom + window.scrollY > window.innerHeight + 0.5) {
                const parts = [...w.children].filter((c) => c.offsetHeight)
                  .map((c) => `${c.className.split(' ')[0]} ${c.offsetHeight}`).join(', ');
                const y = Math.round(r.bottom + window.scrollY);
                const said = `${w.dataset.state}:${w.dataset.phase || ''}: ${sel} ends at ${y} (${parts})`;
                if (!window.seen.offScreen.includes(said)) window.seen.offScreen.push(said);
              }
            }
          };
          const look = () => {
            const w = document.querySelector('.wizard'), g = document.querySelector('.gauge-text');
            // the turn's angle: while turning, and while the device is put down (the gauge holds the turn's angle; on a
            // busy machine the page may see a fast turn's last part only then)
            if (w && g && ['turning', 'placing'].includes(w.dataset.phase)) {
              const n = parseInt(g.textContent, 10), axis = w.dataset.state.slice(5);
              if (!Number.isNaN(n)) window.seen.gauge[axis] = Math.max(window.seen.gauge[axis] || 0, n);
            }
            // the gauge's size through each turn without a notice (it changed when the turn stopped: 277 to 237 px)
            const wrap = document.querySelector('.gauge-wrap'), box = document.querySelector('.notice-box');
            if (w && wrap && ['ready', 'turning', 'placing'].includes(w.dataset.phase) && !(box && box.textContent.trim())) {
              const sizes = window.seen.gaugeWidth[w.dataset.state] = window.seen.gaugeWidth[w.dataset.state] || [];
              const px = Math.round(wrap.getBoundingClientRect().width);
              if (!sizes.includes(px)) sizes.push(px);
            }
            if (w && g && w.dataset.phase === 'turning') {
              const axis = w.dataset.state.slice(5);
              const texts = window.seen.gaugeText[axis] = window.seen.gaugeText[axis] || [];
              if (!texts.includes(g.textContent)) texts.push(g.textContent);
              window.seen.targets[axis] = document.querySelector('.gauge-wrap').dataset.target;
            }
            if (document.querySelector('.ring-wrap.moving')) window.seen.ringMoving = true;
            // the turns shown asked again after they were shown done (their tile says "again")
            for (const t of document.querySelectorAll('.tile[data-state="again"] .tile-axis')) {
              const axis = t.textContent.slice(-1).toLowerCase();
              if (!window.seen.again.includes(axis)) window.seen.again.push(axis);
            }
            for (const n of document.querySelectorAll('.notice')) {
              const t = n.textContent.trim();
              if (!window.seen.notices.includes(t)) window.seen.notices.push(t);
            }
          };
          new MutationObserver(() => {
            look();
            sample();
            offScreen();
            const w = document.querySelector('.wizard'), hl = document.querySelector('.instruction');
            if (hl && last(window.seen.headlines) !== hl.textContent) window.seen.headlines.push(hl.textContent);
            const sp = w ? `${w.dataset.state}:${w.dataset.phase || ''}` : null;
            if (sp && last(window.seen.phases) !== sp) window.seen.phases.push(sp);
            // each screen as first shown, for axe-core afterwards (a screen may last a fraction of a second)
            if (sp && !(sp in window.seen.screens)) window.seen.screens[sp] = document.documentElement.outerHTML;
            const box = document.querySelector('.notice-box'), said = `${sp}|${box ? box.textContent.trim() : ''}`;
            if (sp && last(window.seen.phaseNotices) !== said) window.seen.phaseNotices.push(said);
            const done = [...document.querySelectorAll('.tile[data-state="done"] .tile-axis')]
              .map((t) => t.textContent.slice(-1).toLowerCase()).join('');
            const tiles = w && w.querySelector('.tiles');
            if (tiles && !tiles.hidden && last(window.seen.done) !== done) window.seen.done.push(done);
            if (w && w.dataset.phase === 'placing' && !document.querySelector('.gauge-wrap')) window.seen.placingWithoutGauge = true;
            if (sp) {
              const notices = [...document.querySelectorAll('.notice')].map((n) => `${n.className}|${n.textContent.trim()}`);
              const now = { sp, instruction: text('.instruction'), sub: text('.sub'), recorded: text('.recorded'),
                            recordedClass: (document.querySelector('.recorded') || {}).className || '', notices };
              const before = last(window.seen.shown);
              if (!before || JSON.stringify(before) !== JSON.stringify(now)) window.seen.shown.push(now);
            }
          }).observe(document.body, { subtree: true, childList: true, characterData: true, attributes: true });
        }""")

    def seen(self) -> dict[str, Any]:
        return self.page.evaluate("() => window.seen")

    def shown(self, sp: str) -> list[dict[str, Any]]:
        """What the page said while it showed ``sp`` ("state:phase"), each change in order (``record`` first)."""
        return [s for s in self.seen()["shown"] if s["sp"] == sp]

    def assert_screens_accessible(self) -> list[str]:
        """axe-core on every screen ``record`` saw (state:phase), each as it was first shown, rendered again in a page
        of its own without its scripts (a screen that lasts 0.3 s cannot wait for the audit); returns their names.

        The screens share one audit page: the first is loaded into it; each next one whose head is the same (the title
        aside) takes the place of the one before in that document, so axe-core, loaded once, audits them all."""
        screens: dict[str, str] = self.page.evaluate("() => window.seen.screens")
        page = self.page.context.new_page()
        loaded_head = None
        try:
            for name, html in screens.items():
                static = re.sub(r"<script\b.*?</script>", "", html, flags=re.S | re.I)
                head = re.sub(r"<title>.*?</title>", "", static.split("</head>", 1)[0], flags=re.S)
                if head == loaded_head:
                    page.evaluate(_SWAP_DOCUMENT, static)
                else:
                    page.set_content(static.replace("<head>", f'<head><base href="{self.service.base}/">', 1), wait_until="load")
                    loaded_head = head
                assert_accessible(page, f"screen {name}")
        finally:
            page.close()
        return list(screens)

    def small_targets(self) -> list[str]:
        """Visible links, buttons, inputs and summaries smaller than 44 x 44 CSS px."""
        return self.page.evaluate("""() => [...document.querySelectorAll('a, button, input, summary')]
          .filter((el) => el.offsetParent !== null)
          .map((el) => [el, el.getBoundingClientRect()])
          .filter(([el, r]) => r.width > 0 && (r.width < 44 || r.height < 44))
          .map(([el, r]) =>
            `${el.tagName.toLowerCase()} "${el.textContent.trim().slice(0, 30)}" ${Math.round(r.width)}x${Math.round(r.height)}`)""")


def assert_accessible(page: Any, where: str) -> None:
    """axe-core (the engine browsers' accessibility audits use) finds no violation of its WCAG 2.x A/AA rules and best
    practices on the page as it is now (axe-core is loaded into a document once, for all its audits)."""
    if not page.evaluate("() => typeof window.axe !== 'undefined'"):
        page.evaluate(_axe_script())
    found = page.evaluate("() => axe.run({resultTypes: ['violations']}).then((results) => results.violations)")
    lines = [f"{v['id']} ({v['impact']}): {v['help']} -- " + "; ".join(n["target"][0] if n["target"] else "?" for n in v["nodes"][:4])
             for v in found]
    assert not lines, f"accessibility violations on {where!r}:\n" + "\n".join(lines)


@functools.cache
def _axe_script() -> str:
    """axe-core's script, as the axe-playwright-python package ships it."""
    from axe_playwright_python.sync_playwright import Axe

    return Axe().axe_script


# one recorded screen in place of another in the same document: the root's attributes, the title and the body
_SWAP_DOCUMENT = """(html) => {
  const next = new DOMParser().parseFromString(html, 'text/html'), root = document.documentElement;
  for (const a of [...root.attributes]) root.removeAttribute(a.name);
  for (const a of next.documentElement.attributes) root.setAttribute(a.name, a.value);
  document.title = next.title;
  document.body.replaceWith(document.adoptNode(next.body));
}"""


def assert_turns_end_with_hold_still(headlines: list[str]) -> None:
    """Every turn's headline went from turning to "Hold it still" to done, and never told her to keep turning.

    "Checking" may be missing: when the readings of the turn's closing rest reach a busy service together, the
    stage detector closes the turn in the same step that would have said "checking", and the page goes straight to
    done, which is then the truth."""
    assert not any(h.startswith("Keep turning") for h in headlines), headlines
    for axis in "XYZ":
        i = headlines.index(f"Turning about {axis}")
        after = [h for h in headlines[i + 1:i + 4] if h != f"Checking turn {axis} — hold still"]
        assert after[:2] == ["Hold it still", f"{axis} done — hold still"], headlines


def assert_done_never_undone(done: list[str], again: Collection[str] = ()) -> None:
    """A turn the tiles showed done stays done: what the page said counted is never taken back (``again``: but for
    the turns whose tile said so, asked again by the result)."""
    for before, after in zip(done, done[1:], strict=False):
        assert set(before) - set(after) <= set(again), f"a turn shown done was taken back without a word: {done}"


# what the page played and read aloud (window.heard: said, tones), recorded from the page's first script on
LISTEN = """
  window.heard = { said: [], tones: [], played: [] };
  if (window.speechSynthesis) {
    const speak = window.speechSynthesis.speak.bind(window.speechSynthesis);
    window.speechSynthesis.speak = (u) => { window.heard.said.push(u.text); try { speak(u); } catch (e) {} };
  }
  const osc = AudioContext.prototype.createOscillator;
  AudioContext.prototype.createOscillator = function () {
    const o = osc.call(this);
    const start = o.start.bind(o);
    // each tone's pitch, and in ``played`` its pitch with the audio clock's times it was asked for and starts at
    o.start = (...a) => {
      window.heard.tones.push(o.frequency.value);
      window.heard.played.push([o.frequency.value, this.currentTime, a.length ? a[0] : this.currentTime]);
      start(...a);
    };
    return o;
  };
"""


def assert_clean(watch: Watch, allowed_errors: tuple[str, ...] = ()) -> None:
    """No request left this computer, none had to be refused, and the console shows no error."""
    assert watch.requests, "the page made no requests at all"
    outside = [u for u in watch.requests if not _is_local(u)]
    assert not outside and not watch.blocked, f"requests to other hosts: {outside or watch.blocked}"
    errors = [e for e in watch.console_errors if not any(a in e for a in allowed_errors)]
    assert not errors, f"console errors: {errors}"


def api(service: RunningService, token: str | None = None) -> httpx.Client:
    """An HTTP client of the service (the API token's operator is 'api')."""
    return service.client(token) if token else service.client()


def upload_accepted(service: RunningService, device: str, seed: int, operator_token: str | None = None,
                    **sensor: Any) -> dict[str, Any]:
    """Calibrate a simulated recording uploaded for a device and accept it; returns the stored calibration. ``sensor``:
    more of what the upload says about its sensor (serial, boot_count)."""
    from calib.io.readers import write_native_csv
    from calib.simulator import simulate

    rec, _ = simulate(seed, noise=0.03)
    buf = io.StringIO()
    write_native_csv(rec, buf)
    with api(service, operator_token) as c:
        r = c.post(
            f"/devices/{device}/calibrate",
            content=buf.getvalue(),
            headers={"Content-Type": "text/csv"},
            params={"sensor_model": "ICM-20948", "firmware": "1.2.0", **sensor},
        )
        assert r.status_code == 200, r.text
        assert r.json()["passed"], r.json()
        r = c.post(f"/sessions/{r.json()['session_id']}/accept")
        assert r.status_code == 200, r.text
        return r.json()["calibration"]


def sign_in_token(service: RunningService) -> str:
    r = httpx.post(service.base + "/auth/login", json={"operator": OPERATOR, "secret": SECRET}, timeout=30, verify=False)
    assert r.status_code == 200, r.text
    return r.json()["token"]


def sign_in_with_pin(w: Wizard, wrong_first: bool = False) -> None:
    w.page.goto(w.service.base + "/")
    w.page.wait_for_selector("#operator")
    w.page.click("button.mode-pin")
    assert w.page.locator("#pin").is_visible() and not w.page.locator("#secret").is_visible()
    assert w.page.get_attribute("#pin", "inputmode") == "numeric"
    w.page.fill("#operator", OPERATOR)
    if wrong_first:
        w.page.fill("#pin", "0000")
        w.page.click("form.signin button[type=submit]")
        w.page.wait_for_selector(".form-error:has-text('do not match')")
    w.page.fill("#pin", PIN)
    w.shot("sign-in-pin")
    w.page.click("form.signin button[type=submit]")
    w.page.wait_for_selector(".device-card")


def start_recorded(w: Wizard, device: str) -> None:
    """Sign in with the PIN, start a calibration of ``device`` and record what the page shows from then on."""
    sign_in_with_pin(w)
    w.page.click(f".device-card[data-device='{device}'] a.button.primary")
    w.page.click(".wizard[data-state='place'] button.primary:not([disabled])")
    w.page.wait_for_url(re.compile(r"#/session/[0-9a-f]{32}$"))
    w.record()


def session_told(w: Wizard) -> str:
    """What the service kept of the session on the page (its warnings, turns, sections and losses), for a failure's
    message: a result that is not the one expected names what the session saw."""
    sid = w.page.url.rsplit("/", 1)[1]
    with api(w.service) as c:
        s = c.get(f"/sessions/{sid}").json()
        sections = c.get(f"/sessions/{sid}/sections")
    kept = {k: s.get(k) for k in ("state", "reason", "warnings", "turns", "lost_samples")}
    return json.dumps({**kept, "sections": sections.json() if sections.status_code == 200 else sections.status_code,
                       "page": w.text(".wizard")})
