"""The page as a clinician meets it, with simulated clinicians who follow what the page says (mock_device.hand,
reading the session's events from the service as the page does), in Chromium at 1280x800 and 820x1180:
sign-in with a PIN, the overview before Start, a picture of hands, device and block for each turn, the layout
that keeps the gauge large and the tiles on screen, a result that says what it means for the study, a clinician who
watches the gauge, a phone, and the history table and plots. Every clinician's whole session at the three sizes, a
knock, a turn done wrong and a stalled retry among them, is in test_webui_moments."""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from webui_fixtures import (
    LISTEN,
    PHONE_VIEW,
    VIEWS,
    WRONG_PIN,
    Watch,
    Wizard,
    api,
    assert_clean,
    assert_turns_end_with_hold_still,
    session_told,
    sign_in_with_pin,
    upload_accepted,
    watched_page,
)
from webui_moments import assert_every_moment_held

from calib.apply.correction import Correction
from calib.io.readers import read_recording, write_native_csv
from calib.simulator import simulate


@pytest.fixture
def hand_wizard(browser: Any, hand_service: Any, page_watch: Watch, artifacts: Path, request: pytest.FixtureRequest) -> Iterator[Wizard]:
    """A page on the service whose wearables are handled by prompt-following clinicians; viewport by parameter."""
    view = getattr(request, "param", None) or "1280x800"
    with watched_page(browser, hand_service, page_watch, VIEWS[view], timeout_ms=45_000, phone=view == PHONE_VIEW) as pg:
        yield Wizard(pg, hand_service, artifacts / "webui" / request.node.name)


def box(w: Wizard, selector: str) -> dict[str, float]:
    b = w.page.locator(selector).first.bounding_box()
    assert b is not None, f"{selector} is not shown"
    return b


def on_first_screen(w: Wizard, selector: str) -> bool:
    """Whether the element ends within the first screenful of the page (whatever the page has scrolled to)."""
    return bool(w.page.evaluate("""(sel) => { const r = document.querySelector(sel).getBoundingClientRect();
      return r.bottom + window.scrollY <= window.innerHeight; }""", selector))


def session_snapshot(w: Wizard, sid: str) -> dict[str, Any]:
    with api(w.service) as c:
        return c.get(f"/sessions/{sid}").json()


def run_to_result(w: Wizard, device: str, check_turns: bool = True, before_start: Callable[[], None] | None = None) -> str:
    """Choose ``device``, check the overview, press Start and follow the session to its end; returns its id."""
    w.page.click(f".device-card[data-device='{device}'] a.button.primary")
    w.page.wait_for_selector(".wizard[data-state='place'] button.primary:not([disabled])")
    overview = w.text(".overview")
    assert "3 turns, about 30 s" in overview and all(f"Turn {a}" in overview for a in "XYZ"), overview
    assert w.page.locator(".overview .turn-guide").count() == 3
    assert on_first_screen(w, ".wizard[data-state='place'] button.primary"), "Start is below the fold"
    w.shot("place")
    if before_start is not None:
        before_start()
    w.page.click(".wizard[data-state='place'] button.primary")
    w.page.wait_for_url(re.compile(r"#/session/[0-9a-f]{32}$"))
    sid = w.page.url.rsplit("/", 1)[1]
    w.record()
    if check_turns:
        for axis in "xyz":
            w.page.wait_for_selector(f".wizard[data-state='turn_{axis}'] .turn-guide-{axis}")
            # the picture of the turn: the table, the block, the device and two hands holding it
            assert w.page.locator(f".turn-guide-{axis} .hand").count() == 2
            assert "block" in w.page.locator(f".turn-guide-{axis}").inner_html()
            label = w.page.get_attribute(f".turn-guide-{axis}", "aria-label") or ""
            assert "put it back against the block" in label.lower() or "back against the block" in label, label
            if axis == "x":
                w.page.wait_for_selector(".wizard[data-state='turn_x'][data-phase='turning']")
                tiles = box(w, ".tiles")
                assert tiles["y"] + tiles["height"] <= w.page.viewport_size["height"], "the turn tiles are off the screen"
                w.shot("turning")
    w.page.wait_for_selector(".verdict h1", timeout=90_000)
    return sid


@pytest.mark.parametrize("hand_wizard", ["1280x800", "820x1180"], indirect=True)
def test_a_careful_clinician_following_the_page_reaches_a_result_that_says_what_it_means(
    hand_wizard: Wizard, page_watch: Watch, request: pytest.FixtureRequest
) -> None:
    w = hand_wizard
    landscape = "1280" in request.node.name
    device = "mock-1" if landscape else "mock-2"
    if landscape:
        w.page.add_init_script(LISTEN)
    sign_in_with_pin(w, wrong_first=True)
    sub = w.text(f".device-card[data-device='{device}'] .dev-sub")
    assert sub.count("wearable") <= 1 and "simulated" in sub, sub  # each fact once
    sid = run_to_result(w, device, before_start=(lambda: identify_and_turn_sound_on(w, device)) if landscape else None)
    if landscape:
        assert_heard_each_step(w)
    seen = w.seen()
    assert_every_moment_held(seen, phone=False)
    # the gauge keeps its size from the turn's prompt to the device put down (the headline grows when the turn stops)
    assert len(seen["gaugeWidth"]) == 3 and all(max(px) - min(px) <= 1 for px in seen["gaugeWidth"].values()), seen["gaugeWidth"]
    assert any(h.startswith("Turn X: ") for h in seen["headlines"]), seen["headlines"]
    assert_turns_end_with_hold_still(seen["headlines"])
    assert w.text(".verdict h1") == "PASS"
    snap = session_snapshot(w, sid)
    near = [c for c in snap["checks"] if c["near_limit"]]
    ready = w.text(".verdict .ready")
    assert ready == ("Ready for the study, with a caution" if near else "Ready for the study"), (ready, near)
    # a k close to its limit does not look like one close to 1: the verdict is marked and the value named
    assert w.page.locator(".verdict.near-limit").count() == (1 if near else 0)
    assert w.page.locator(".near-limits li").count() == len(near)
    for c in near:
        assert w.page.locator(f".near-limits li[data-check='{c['name']}:{c['axis']}']").count() == 1
    # how much better it now measures, in degrees of a full turn, as the service computed it
    acc = snap["accuracy"]
    line = w.text(".accuracy")
    assert f"up to {acc['before_deg']:.0f}° off" in line and "now measures a full turn to within" in line, line
    assert on_first_screen(w, "button.accept"), "Accept & save is below the fold"
    w.shot("pass")
    # the engineer's details: each turn read raw and with the calibration, not "measured 301°"
    w.page.click("details.details summary")
    w.page.wait_for_selector(".plot svg path.series.after")
    heads = w.page.locator("table.turns thead th").all_inner_texts()
    assert heads[:3] == ["Full turn", "Sensor read, raw", "With this calibration: ends from its start"], heads
    raw = [t.split("°")[0] for t in w.page.locator("table.turns tbody td:nth-child(2)").all_inner_texts()]
    ends = [float(t.rstrip("°")) for t in w.page.locator("table.turns tbody td:nth-child(3)").all_inner_texts()]
    assert len(ends) == 3 and all(v < 0.25 for v in ends), ends
    # uncalibrated, a true full turn reads 360°/k: the worst axis is how far it was off; the hand's turns read about that
    k = snap["result"]["k"]
    assert acc["before_with"] == "raw" and acc["before_deg"] == pytest.approx(max(abs(360 / v - 360) for v in k), abs=0.01)
    assert all(abs(float(r) - 360 / v) < 15 for r, v in zip(raw, k, strict=True)), (raw, k)
    # the turns' labels have a strip of their own: no curve runs through them
    for fig in w.page.locator("figure.plot").all():
        top = min(b["y"] for b in (p.bounding_box() for p in fig.locator("path.series").all()) if b)
        for lab in fig.locator("text.band-label").all():
            lb = lab.bounding_box()
            assert lb is not None and lb["y"] + lb["height"] <= top + 0.5, (lb, top)
    w.shot("details")
    # a device never calibrated, discarded: the page says so without asking for a calibration that is not there
    w.page.click("button:has-text('Discard')")
    w.page.wait_for_selector(".verdict.neutral")
    w.page.wait_for_selector(".sentence:has-text('has no calibration yet')")
    assert_clean(page_watch, allowed_errors=WRONG_PIN)


@pytest.mark.parametrize("hand_wizard", ["820x1180"], indirect=True)
def test_portrait_gives_the_gauge_and_ring_the_height(hand_wizard: Wizard, page_watch: Watch) -> None:
    w = hand_wizard
    sign_in_with_pin(w)
    # the cards' buttons wrap beside the name; a name never breaks ("mock-/1")
    heights = w.page.eval_on_selector_all(".device-card h2", "(hs) => hs.map((e) => e.getBoundingClientRect().height)")
    assert heights and max(heights) < 40, heights
    w.page.click(".device-card[data-device='mock-4'] a.button.primary")
    w.page.click(".wizard[data-state='place'] button.primary:not([disabled])")
    w.page.wait_for_selector(".wizard[data-state='still'] .ring-wrap")
    ring = box(w, ".ring-wrap")
    w.page.wait_for_selector(".wizard[data-state='turn_x'] .gauge-wrap")
    gauge = box(w, ".gauge-wrap")
    tiles = box(w, ".tiles")
    height = w.page.viewport_size["height"]
    # the old layout capped both at 290 px and left 40 % of a portrait tablet empty
    assert ring["width"] >= 380 and gauge["width"] >= 380, (ring, gauge)
    assert tiles["y"] + tiles["height"] <= height and tiles["y"] + tiles["height"] >= 0.85 * height, tiles
    w.shot("portrait-turn")
    w.page.wait_for_selector(".verdict h1", timeout=90_000)
    assert_clean(page_watch)


def identify_and_turn_sound_on(w: Wizard, device: str) -> None:
    """Her eyes are on the device: Identify (beside Start) makes the chosen wearable blink (the simulated one's light
    goes on); Sound and Read aloud are off until she turns them on, and remembered after a reload."""
    w.page.click(".wizard[data-state='place'] .identify-slot button.identify")
    w.page.wait_for_selector(".wizard[data-state='place'] .identify-status.ok")
    assert "blinks its light for 5 s" in w.text(".identify-status")
    with api(w.service) as c:
        assert c.get(f"/devices/{device}").json()["simulated_identifying"] is True
    toggles = [f".wizard[data-state='place'] .cue-{t}" for t in ("sound", "speech")]
    assert all(w.page.get_attribute(t, "aria-pressed") == "false" for t in toggles)
    for t in toggles:
        w.page.click(t)
    w.page.reload()
    w.page.wait_for_selector(".wizard[data-state='place'] button.primary:not([disabled])")
    assert all(w.page.get_attribute(t, "aria-pressed") == "true" for t in toggles)
    w.shot("sound-on")
    w.record()  # the reload cleared the recorder


def assert_heard_each_step(w: Wizard) -> None:
    """Every step had a tone and the result a higher one; the prompts were read aloud as the page showed them."""
    heard = w.page.evaluate("() => window.heard")
    said = heard["said"]
    for axis in "XYZ":
        assert f"Turning about {axis}" in said and f"Checking turn {axis} — hold still" in said, said
    assert said[-1] == "PASS" and "Hold still" in said, said
    assert heard["tones"].count(880) >= 10 and heard["tones"][-1] == 1320, heard["tones"]


def test_a_clinician_who_watches_the_gauge_stops_at_360_degrees(hand_wizard: Wizard, page_watch: Watch) -> None:
    """The gauge-watcher's first session has no target (the device was never calibrated) and is accepted; in the
    second the gauge shows true degrees and the hand stops when it reads 360°."""
    w = hand_wizard
    sign_in_with_pin(w)
    run_to_result(w, "mock-3", check_turns=False)
    assert w.text(".verdict h1") == "PASS"
    w.page.click("button.accept")
    w.page.wait_for_selector(".verdict.saved")
    # she verifies it with one more turn, prompted by the page as the service sees her hand
    w.page.click("button.verify")
    w.page.wait_for_selector(".verification.ok", timeout=90_000)
    assert "calibrated" in w.text(".verification-angles") and "raw" in w.text(".verification-angles")
    w.page.goto(w.service.base + "/#/devices")
    w.page.wait_for_selector(".device-card[data-device='mock-3'] .calibrated")
    run_to_result(w, "mock-3", check_turns=False)
    seen = w.seen()
    assert_every_moment_held(seen, phone=False)
    assert w.text(".verdict h1") == "PASS", session_told(w)
    assert set(seen["targets"].values()) == {"360"}, seen["targets"]
    assert all(335 <= seen["gauge"][a] <= 385 for a in "xyz"), seen["gauge"]
    assert_clean(page_watch)


def test_the_history_table_keeps_each_value_and_date_on_one_line(hand_wizard: Wizard, hand_service: Any, page_watch: Watch) -> None:
    for seed, boot in ((5, 3), (6, 4)):
        upload_accepted(hand_service, "bench-unit-9", seed=seed, serial="BU9-0001", boot_count=boot)
    w = hand_wizard
    sign_in_with_pin(w)
    w.page.goto(w.service.base + "/#/history/bench-unit-9")
    w.page.wait_for_selector("table.calibrations")
    broken = w.page.evaluate("""() => [...document.querySelectorAll('table.calibrations .val, table.calibrations .when > span')]
      .filter((el) => el.getClientRects().length !== 1
        || el.getBoundingClientRect().height > 1.6 * parseFloat(getComputedStyle(el).fontSize))
      .map((el) => el.textContent)""")
    assert broken == [], broken
    assert w.page.locator("table.calibrations tbody tr").count() == 2
    # the calibration in force at a moment: none before the first, the latest one later on, with its age warned of
    w.page.fill("#in-force-at", "2001-01-01T10:00:00")
    w.page.click("form.in-force button")
    w.page.wait_for_selector(".in-force-out:has-text('had been accepted by then')")
    w.page.fill("#in-force-at", "2099-01-01T10:00:00")
    w.page.click("form.in-force button")
    w.page.wait_for_selector(".in-force-answer")
    with api(hand_service) as c:
        newest = c.get("/devices/bench-unit-9/calibration").json()
    assert f"Calibration #{newest['id']} (row 1 below)" in w.text(".in-force-answer")
    assert "more than the 30 days allowed" in w.text(".in-force-out")
    assert "serial BU9-0001 · power-up #4" in w.text("table.calibrations tbody tr:first-child")
    # a recording of power-up #3 takes that power-up's calibration, even asked about a later moment
    w.page.fill("#in-force-boot", "3")
    w.page.click("form.in-force button")
    w.page.wait_for_selector(".in-force-answer:has-text('Measured in that power-up')")
    assert "(row 2 below)" in w.text(".in-force-answer")
    w.page.fill("#in-force-boot", "")
    # a study recording corrected by the calibration in force, downloaded from the page
    rec, _ = simulate(12, noise=0.03)
    study = Path(w.shots) / "study.csv"
    write_native_csv(rec, study)
    w.page.set_input_files("#apply-file", str(study))
    w.page.click("form.apply button")
    w.page.wait_for_selector(f"form.apply .in-force-answer:has-text('Corrected with calibration #{newest['id']}')")
    with w.page.expect_download() as dl:
        w.page.click("form.apply a.download")
    got = read_recording(dl.value.path())
    assert np.allclose(got.gyro, rec.gyro @ np.diag(newest["k"]).T + np.asarray(newest["b"]), atol=1e-9)
    # and its orientation before and after, plotted
    w.page.check("#apply-orientation")
    w.page.click("form.apply button")
    w.page.wait_for_selector("form.apply .plots.orientation figure >> nth=3")
    assert "the orientation ends" in w.text("form.apply .in-force-out")
    w.shot("history-orientation")
    w.page.uncheck("#apply-orientation")
    # never another sensor's calibration: the page says so and offers no file
    w.page.fill("#apply-serial", "BU9-0002")
    w.page.click("form.apply button")
    w.page.wait_for_selector("form.apply .form-error:has-text('another sensor')")
    assert w.page.locator("form.apply a.download").count() == 0
    # a calibration made elsewhere (gyrocal's JSON here) imported into the history: the newest row, marked imported
    made = Path(w.shots) / "bench-turntable.json"
    made.write_text(json.dumps(Correction(K=np.diag([1.02, 0.98, 1.0]), b=np.array([0.2, -0.1, 0.05])).to_json()))
    w.page.set_input_files("#import-file", str(made))
    w.page.fill("#import-serial", "BU9-0001")
    w.page.click("form.import button")
    w.page.wait_for_selector("table.calibrations tbody tr:nth-child(3)")
    assert "imported file" in w.text("table.calibrations tbody tr:first-child")
    w.shot("history")
    assert_clean(page_watch, allowed_errors=("409 (Conflict)",))  # the refused apply



def test_a_result_unlike_the_devices_history_is_named_before_accept(hand_wizard: Wizard, hand_service: Any, page_watch: Watch) -> None:
    from calib.simulator import SensorParams

    sensor = SensorParams(k=np.array([1.05, 0.96, 1.02]), b=np.array([0.8, -1.1, 0.4]))

    def upload(seed: int, params: SensorParams) -> dict[str, Any]:
        rec, _ = simulate(seed, noise=0.03, params=params)
        path = Path(hand_wizard.shots) / f"upload-{seed}.csv"
        write_native_csv(rec, path)
        with api(hand_service) as c:
            r = c.post("/devices/bench-unit-11/calibrate", content=path.read_text(), headers={"Content-Type": "text/csv"},
                       params={"sensor_model": "ICM-20948", "firmware": "1.2.0"})
            assert r.status_code == 200, r.text
            return r.json()

    for seed in (31, 32):
        with api(hand_service) as c:
            assert c.post(f"/sessions/{upload(seed, sensor)['session_id']}/accept").status_code == 200
    knocked = upload(33, SensorParams(k=sensor.k * np.array([1.0, 1.05, 1.0]), b=sensor.b))
    w = hand_wizard
    sign_in_with_pin(w)
    w.page.goto(f"{w.service.base}/#/session/{knocked['session_id']}")
    w.page.wait_for_selector(".departures li[data-departure='k:y']")
    assert w.text(".verdict .ready") == "Ready for the study, with a caution"
    assert "earlier calibrations" in w.text(".departures") and "dropped or knocked" in w.text(".departures")
    w.shot("departure")
    assert_clean(page_watch)


PHONE = {"width": 390, "height": 844}


def fits_the_screen(w: Wizard) -> None:
    """Nothing to scroll sideways, and nothing of the top bar cut off."""
    wide, shown = w.page.evaluate("() => [document.documentElement.scrollWidth, document.documentElement.clientWidth]")
    if wide > shown:
        over = w.page.evaluate("""(shown) => [...document.querySelectorAll('main *')]
          .filter((el) => el.getBoundingClientRect().right > shown + 0.5)
          .slice(0, 6).map((el) => `${el.tagName.toLowerCase()}.${el.className} ${Math.round(el.getBoundingClientRect().right)}`)""",
                               shown)
        raise AssertionError(f"the page is {wide} px wide on a {shown} px screen: {over}")
    for b in w.page.locator(".topbar a, .topbar button").all():
        r = b.bounding_box()
        assert r is not None and r["x"] >= 0 and r["x"] + r["width"] <= shown, (b.inner_text(), r)


def test_a_phone_is_a_first_class_screen(browser: Any, hand_service: Any, page_watch: Watch, artifacts: Path) -> None:
    """At 390x844 in a phone's browser, touch only: the page is as wide as the screen (nothing cut, nothing to scroll
    sideways), Start, Details and Discard take a tap, the gauge takes most of the width with the turn's tiles on the
    first screen below it, not over it; every screen passes axe-core."""
    with watched_page(browser, hand_service, page_watch, PHONE, timeout_ms=45_000, phone=True) as pg:
        w = Wizard(pg, hand_service, artifacts / "webui" / "test_a_phone")
        sign_in_with_pin(w)
        fits_the_screen(w)
        w.shot("phone-devices")
        w.page.tap(".device-card[data-device='mock-4'] a.button.primary")
        start = ".wizard[data-state='place'] button.primary:not([disabled])"
        w.page.wait_for_selector(start)
        fits_the_screen(w)
        w.shot("phone-place")
        w.page.tap(start)
        w.page.wait_for_selector(".wizard[data-state='turn_x'] .gauge-wrap")
        # both measured at one moment: the headline above them changes from "Turn X: ..." to "Turning about X"
        gauge, tiles = w.page.evaluate("""() => [".gauge-wrap", ".tiles"].map((sel) => {
          const r = document.querySelector(sel).getBoundingClientRect();
          return { x: r.x, y: r.y, width: r.width, height: r.height }; })""")
        assert gauge["width"] >= 0.65 * PHONE["width"], gauge
        assert tiles["y"] >= gauge["y"] + gauge["height"] and on_first_screen(w, ".tiles"), (gauge, tiles)
        assert on_first_screen(w, ".gauge-wrap") and w.page.locator(".instruction").is_visible()
        # the step's name beside Cancel stays whole ("Step 3 of 7 · Turn" over "X" before)
        assert w.page.evaluate("document.querySelector('.step-name').getClientRects().length") == 1
        fits_the_screen(w)
        w.shot("phone-turn")
        w.page.wait_for_selector(".verdict h1", timeout=90_000)
        fits_the_screen(w)
        w.shot("phone-result")
        w.page.tap("details.details summary")
        assert w.page.locator(".wizard[data-decision='accepted']").count() == 0
        try:
            w.page.wait_for_selector(".plot svg path.series.after")
        except Exception as exc:  # a failure names what the page shows and asked for, not only that it waited
            shown = w.page.evaluate("() => [document.querySelector('details.details').open, document.querySelector('.plots, .plot') ? "
                                    "document.querySelector('.plots, .plot').textContent.slice(0, 400) : null]")
            asked = [u for u in page_watch.requests if "/plot" in u or "/diagnosis" in u]
            raise AssertionError(f"no plot after Details was opened: (open, plot box) {shown}; requests {asked}; "
                                 f"console {page_watch.console_errors}") from exc
        fits_the_screen(w)
        w.shot("phone-details")
        w.page.tap("button:has-text('Discard')")
        w.page.wait_for_selector(".verdict.neutral")
        w.page.goto(f"{hand_service.base}/#/history/mock-4")
        w.page.wait_for_selector("table.history.sessions")
        fits_the_screen(w)
        w.shot("phone-history")
    assert_clean(page_watch, allowed_errors=WRONG_PIN)

