"""The page as a clinician meets it, with simulated clinicians who follow what the page says (mock_device.hand,
reading the session's events from the service as the page does), in Chromium at 1280x800 and 820x1180:
sign-in with a PIN, the overview before Start, a picture of hands, device and block for each turn, the layout
that keeps the gauge large and the tiles on screen, a result that says what it means for the study, a bump
recovered without restarting, a clinician who watches the gauge, and the history table and plots."""

from __future__ import annotations

import contextlib
import json
import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from webui_fixtures import (
    LISTEN,
    OPERATOR,
    PIN,
    Watch,
    Wizard,
    api,
    assert_clean,
    assert_done_never_undone,
    assert_turns_end_with_hold_still,
    upload_accepted,
    watched_page,
)
from webui_moments import assert_every_moment_held, assert_retry_reasons_stay

from calib.apply.correction import Correction
from calib.io.readers import read_recording, write_native_csv
from calib.simulator import simulate

VIEWS = {"1280x800": {"width": 1280, "height": 800}, "820x1180": {"width": 820, "height": 1180}, "390x844": {"width": 390, "height": 844}}
PHONE_VIEW = "390x844"  # a phone's browser: touch only, at its pixel density


@pytest.fixture
def hand_wizard(browser: Any, hand_service: Any, page_watch: Watch, artifacts: Path, request: pytest.FixtureRequest) -> Iterator[Wizard]:
    """A page on the service whose wearables are handled by prompt-following clinicians; viewport by parameter."""
    view = getattr(request, "param", None) or "1280x800"
    with watched_page(browser, hand_service, page_watch, VIEWS[view], timeout_ms=45_000, phone=view == PHONE_VIEW) as pg:
        yield Wizard(pg, hand_service, artifacts / "webui" / request.node.name)


WRONG_PIN = ("401 (Unauthorized)",)  # the console's line for the wrong PIN a test types on purpose


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


def start_recorded(w: Wizard, device: str) -> None:
    """Sign in with the PIN, start a calibration of ``device`` and record what the page shows from then on."""
    sign_in_with_pin(w)
    w.page.click(f".device-card[data-device='{device}'] a.button.primary")
    w.page.click(".wizard[data-state='place'] button.primary:not([disabled])")
    w.page.wait_for_url(re.compile(r"#/session/[0-9a-f]{32}$"))
    w.record()


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
    w.page.click(".device-card[data-device='mock-5'] a.button.primary")
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


@pytest.mark.parametrize("hand_wizard", [PHONE_VIEW], indirect=True)
def test_a_bump_in_a_pause_is_warned_and_recovered_without_restarting(hand_wizard: Wizard, page_watch: Watch) -> None:
    w = hand_wizard
    start_recorded(w, "mock-3")
    w.page.wait_for_selector(".notice.warn")
    # the warning takes the stage's height, not the tiles' place on the screen
    tiles = box(w, ".tiles")
    assert tiles["y"] + tiles["height"] <= w.page.viewport_size["height"], tiles
    w.shot("bumped")
    w.page.wait_for_selector(".verdict h1", timeout=90_000)
    assert w.text(".verdict h1") == "PASS", session_told(w)
    seen = w.seen()
    assert seen["ringMoving"], "the ring never showed the device moving"
    # on a phone, Cancel, the ring or gauge and the turn tiles on the first screen at every moment, under the knock's
    # notice too (its 13 bold lines pushed the ring and the tiles below it); and every other moment held
    assert_every_moment_held(seen, phone=True)
    assert any("moving" in n or "moved" in n for n in seen["notices"]), seen["notices"]
    # a turn counts once its closing rest is complete: a knock before that asks for the turn again and its tile was
    # never shown done; a knock after it only restarts the pause and the tile stays done, whatever the screen
    assert_done_never_undone(seen["done"])
    moved = [n for n in seen["notices"] if "moved during the pause" in n]
    assert moved and all(("could be checked" in n) == ("turn again" in n) for n in moved), moved
    assert not seen["placingWithoutGauge"], "the gauge went away before the device was still"
    assert_clean(page_watch)


ASKED_AGAIN = {"z": "mock-6", "y": "mock-7"}  # the hand that stops Z short, the one that puts Y down tilted


@pytest.mark.parametrize("view", list(VIEWS))
def test_a_turn_done_wrong_is_asked_again_saying_why_never_blaming_the_sensor(
    browser: Any, hand_service: Any, page_watch: Watch, artifacts: Path, view: str
) -> None:
    """mock-6's clinician stops the first Z turn where the device reads 296 deg: the live check takes it, the result's
    k_z is out of range. The page does not end on a FAIL blaming the sensor: it names that turn, says how to make it
    and asks it again in the same session (attempt 2), the X and Y turns kept. mock-7's puts the device down 3 deg
    tilted after the first Y turn: the page says so as soon as that turn is checked ("Turn Y ended 3.0° off where it
    began") and asks it again, never showing Y done before. Both then pass (the two at once, a page each).

    At every moment, on a desktop, a tablet and a phone: the reason stays on screen while she does what it says, from
    the moment it appears until the turn asked again starts; putting the device back is shown as that ("Putting it
    back against the block"), not as the turn."""
    with contextlib.ExitStack() as pages:
        wizards = {asked: Wizard(pages.enter_context(watched_page(browser, hand_service, page_watch, VIEWS[view], timeout_ms=45_000,
                                                                   phone=view == PHONE_VIEW)),
                                 hand_service, artifacts / "webui" / f"asked-again-{asked}-{view}")
                   for asked in ASKED_AGAIN}
        for asked, w in wizards.items():
            start_recorded(w, ASKED_AGAIN[asked])
        for asked, w in wizards.items():
            w.page.wait_for_selector(".verdict h1", timeout=90_000)
            _asked_again_and_passed(w, asked, phone=view == PHONE_VIEW)
    assert_clean(page_watch)


def _asked_again_and_passed(w: Wizard, asked: str, phone: bool) -> None:
    assert w.text(".verdict h1") == "PASS", session_told(w)
    seen = w.seen()  # what the page showed, change by change (the retry's notice may last under a second)
    assert not any("faulty" in n for n in seen["notices"]), seen["notices"]
    assert_retry_reasons_stay(seen["samples"], save=w.shots / "retry-reasons.json")
    assert_every_moment_held(seen, phone=phone)
    put_back = [s for s in seen["samples"] if s[1] == f"turn_{asked}:returning"]
    assert all(s[3] == "Putting it back against the block" for s in put_back), put_back[:3]
    assert put_back or asked == "y", "the Z turn's put-back was not shown as such"  # Y's is put back while it settles
    done = seen["done"]
    if asked == "y":
        off = [n for n in seen["phaseNotices"] if n.startswith("turn_y:") and "Attempt 2 of 3" in n]
        assert off and re.search(r"Turn Y ended 3\.\d° off where it began", off[0]) and "against the block" in off[0], off
        assert_done_never_undone(done)  # Y was not shown done before it was asked again
        assert seen["again"] == [], seen["again"]
    else:
        phases = seen["phases"]
        assert phases[phases.index("computing:") + 1].startswith("turn_z:"), phases  # computed, then that turn again
        again = [n for n in seen["phaseNotices"] if n.startswith("turn_z:") and "Attempt 2 of 3" in n]
        assert again, seen["phaseNotices"]
        assert re.search(r"The turn about Z read 29\d°", again[0]) and "all the way round" in again[0], again[0]
        # the Z tile left "done" only because the result asked that turn again, and said so ("again", not "now"); X and
        # Y never did
        assert "xyz" in done and "xy" in done[done.index("xyz"):], done
        assert seen["again"] == ["z"], seen["again"]
        assert all(set("xy") <= set(d) for d in done[done.index("xy"):]), done
        assert "turn_z:settle" in w.assert_screens_accessible()  # the screen that asks the turn again, audited too


@pytest.mark.parametrize("hand_wizard", [PHONE_VIEW], indirect=True)
def test_a_turn_asked_again_and_never_made_keeps_its_reason_counts_down_and_ends_saying_so(
    hand_wizard: Wizard, page_watch: Watch
) -> None:
    """mock-8's clinician puts the device down tilted after the first Y turn, puts it back when asked again, and then
    waits. The reason stays on screen through the wait, with the hint beneath it when the turn is overdue (never in
    its place); the time left counts down on screen; the session ends saying the next turn was not started in time,
    not that no turn was made (X and Y were)."""
    w = hand_wizard
    start_recorded(w, "mock-8")
    w.page.wait_for_selector(".wizard[data-state='failed'] .verdict h1", timeout=90_000)
    samples = w.seen()["samples"]
    (reason,) = assert_retry_reasons_stay(samples, save=w.shots / "retry-reasons.json")
    assert reason.state == "turn_y" and "off where it began" in reason.text, reason
    ready = [s for s in samples if s[1] == "turn_y:ready" and s[0] >= reason.shown_ms]
    hinted = [s for s in ready if "Waiting for the turn" in s[2]]
    assert hinted and all(reason.text[:40] in s[2] for s in hinted), hinted[:2]  # the hint beside the reason
    left = [int(re.search(r"stops in (\d+) s", s[4]).group(1)) for s in ready if s[4]]
    assert left and left[0] <= 40 and left[-1] <= 5 and left == sorted(left, reverse=True), left
    assert w.seen()["offScreen"] == [], w.seen()["offScreen"]  # the reason, hint and count above: the tiles still on screen
    assert w.text(".verdict h1") == "The next turn was not started in time"
    assert "60 s" in w.text(".sentence"), w.text(".sentence")
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
    run_to_result(w, "mock-4", check_turns=False)
    assert w.text(".verdict h1") == "PASS"
    w.page.click("button.accept")
    w.page.wait_for_selector(".verdict.saved")
    # she verifies it with one more turn, prompted by the page as the service sees her hand
    w.page.click("button.verify")
    w.page.wait_for_selector(".verification.ok", timeout=90_000)
    assert "calibrated" in w.text(".verification-angles") and "raw" in w.text(".verification-angles")
    w.page.goto(w.service.base + "/#/devices")
    w.page.wait_for_selector(".device-card[data-device='mock-4'] .calibrated")
    run_to_result(w, "mock-4", check_turns=False)
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
        w.page.tap(".device-card[data-device='mock-5'] a.button.primary")
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
        w.page.goto(f"{hand_service.base}/#/history/mock-5")
        w.page.wait_for_selector("table.history.sessions")
        fits_the_screen(w)
        w.shot("phone-history")
    assert_clean(page_watch, allowed_errors=WRONG_PIN)

