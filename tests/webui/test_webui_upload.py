"""Calibrating a recording file from the page, in Debian's Chromium against the real service: imucal's labelled
raw-counts session is read with its sensitivities, recognised as Ferraris' protocol and shown as a session.

One recording, one calibration, whichever door it comes through: every real recording of ../shared/data/real and
simulated paper, Ferraris and multi-position recordings, with the options each needs (rate, raw-count
sensitivities, imucal's section list, imu_tk's two files, a protocol), through ``gyrocal calibrate``,
``POST /devices/{id}/calibrate`` and the page's upload form: the same k, b, K and G, or the same refusal."""

from __future__ import annotations

import contextlib
import io
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from webui_fixtures import Watch, Wizard, api, assert_clean, watched_page

from calib.cli.main import main as gyrocal

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


def upload_from_page(wizard: Wizard, page: Any, device: str, path: Path) -> None:
    """Sign in, calibrate the CSV at ``path`` as ``device`` with the page's upload form (no options), and wait for
    its result screen."""
    wizard.sign_in()
    page.click("#upload-link")
    page.wait_for_selector("form.upload-form")
    page.fill("#up-device", device)
    page.set_input_files("#up-file", str(path))
    page.click("form.upload-form button[type=submit]")
    page.wait_for_url("**/#/session/*")
    page.wait_for_selector(".verdict h1")


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
    upload_from_page(wizard, page, "re-oriented", path)
    page.click("details.details summary")
    facts = page.locator("dl.facts").inner_text()
    assert "used: multi-position" in facts
    assert "found and modelled (significant" in facts
    largest = float(re.search(r"up to ([0-9.]+) \(°/s\)/g", facts).group(1))  # type: ignore[union-attr]
    assert abs(largest - 0.12) < 0.01  # the concealed G's largest entry
    assert "without it the gravity residuals were 0.26° rms" in facts and "0.03° rms over 12 motions" in facts
    wizard.shot("upload-g-sensitivity")
    assert_clean(page_watch)


def test_a_scale_factor_near_its_limit_is_said_in_the_sensors_own_terms_either_way(wizard: Wizard, page: Any,
                                                                                     page_watch: Watch, tmp_path: Path) -> None:
    """g = K m: k_x = 1.19 makes a full turn read 302.5°, 16 % low; k_z = 0.82 makes it read 439°, 22 % high. The caution
    says what the sensor reads, in the right direction, never "over-reads" for a sensor that reads low."""
    from calib.io.readers import write_native_csv
    from calib.simulator import SensorParams, simulate

    rec, _ = simulate(11, noise=0.03, params=SensorParams(k=np.array([1.19, 1.0, 0.82]), b=np.array([0.5, -0.3, 0.2])))
    path = tmp_path / "near-limits.csv"
    write_native_csv(rec, path)
    upload_from_page(wizard, page, "near-limits", path)
    assert wizard.text(".verdict h1") == "PASS"
    assert wizard.text(".verdict .ready") == "Ready for the study, with a caution"
    x = wizard.text(".near-limits li[data-check='k:x']")
    z = wizard.text(".near-limits li[data-check='k:z']")
    assert x == "The X axis reads 16 % low: a full turn shows as 303° instead of 360° (from 300° to 450° is allowed).", x
    assert z == "The Z axis reads 22 % high: a full turn shows as 439° instead of 360° (from 300° to 450° is allowed).", z
    assert "over-reads" not in page.inner_text("main") and "under-reads" not in page.inner_text("main")
    wizard.shot("caution-either-way")
    assert_clean(page_watch)


def test_on_a_phone_a_pass_with_a_caution_keeps_accept_on_the_first_screen_and_its_details_fit(
        browser: Any, webui_service: Any, page_watch: Watch, artifacts: Path, tmp_path: Path) -> None:
    """At 390x844, a PASS with two values close to their limits: the caution is read first, and "Accept & save" is
    on the first screen all the same (it was at y 927, below it), at its foot until she scrolls to where it belongs.
    The details' turns table fits the phone: nothing in the Details box scrolls sideways (it was 446 px in 350)."""
    from calib.io.readers import write_native_csv
    from calib.simulator import SensorParams, simulate

    rec, _ = simulate(11, noise=0.03, params=SensorParams(k=np.array([1.19, 1.0, 0.82]), b=np.array([0.5, -0.3, 0.2])))
    path = tmp_path / "near-limits.csv"
    write_native_csv(rec, path)
    with watched_page(browser, webui_service, page_watch, {"width": 390, "height": 844}, phone=True) as page:
        wizard = Wizard(page, webui_service, artifacts / "webui" / "phone-caution")
        upload_from_page(wizard, page, "near-limits-phone", path)
        assert wizard.text(".verdict .ready") == "Ready for the study, with a caution"
        page.evaluate("window.scrollTo(0, 0)")
        where = page.evaluate("""() => { const r = document.querySelector('button.accept').getBoundingClientRect();
          const near = document.querySelector('.near-limits').getBoundingClientRect();
          return { top: r.top, bottom: r.bottom, screen: innerHeight, caution: near.top }; }""")
        assert where["bottom"] <= where["screen"] and where["caution"] < where["top"], where
        wizard.shot("phone-pass-with-a-caution")
        # what is scrolled to (a tap's target, the keyboard's focus: Discard here) comes to rest above the Accept & save
        # kept at the screen's foot, never under it, where a tap meant for it would save the result
        under = page.evaluate("""() => {
          const d = [...document.querySelectorAll('.wizard button')].find((b) => b.textContent.includes('Discard'));
          d.scrollIntoView({ block: 'end' });
          const a = document.querySelector('button.accept').getBoundingClientRect(), r = d.getBoundingClientRect();
          return r.bottom > a.top && r.top < a.bottom ? [r.top, r.bottom, a.top, a.bottom] : null; }""")
        assert under is None, under
        page.click("details.details summary")
        page.wait_for_selector("table.turns")
        wide = page.evaluate("""() => [...document.querySelectorAll('.details, .details table')]
          .filter((el) => el.scrollWidth > el.clientWidth + 0.5).map((el) => [el.className, el.scrollWidth, el.clientWidth])""")
        assert wide == [], wide
        # still on the screen while she reads the details below
        foot = page.evaluate("""() => { const r = document.querySelector('button.accept').getBoundingClientRect();
          return [r.top, r.bottom, innerHeight]; }""")
        assert 0 <= foot[0] and foot[1] <= foot[2], foot
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
    assert "1.30868 ± 0.00031" in page.locator("table.params").inner_text()
    wizard.shot("upload-imu-tk")
    assert_clean(page_watch)


# -- one door ------------------------------------------------------------------------------------------
PARAMETERS = ("k", "b", "K", "G")


@dataclass(frozen=True)
class Case:
    """A recording and what its reader must be told."""

    file: str
    fs: float | None = None
    gyro_counts: float | None = None
    accel_counts: float | None = None
    accel_file: str | None = None
    sections: str | None = None
    protocol: str = "auto"
    methods: tuple[str, ...] = field(default=("closure",))  # the CLI and the API are compared with each


REAL = {
    "imucal-ferraris": Case("imucal/example_ferraris_session.csv", fs=102.4, methods=("closure", "paper", "ferraris")),
    "imucal-ferraris-sections": Case("imucal/example_ferraris_session.csv", fs=102.4,
                                     sections="imucal/example_ferraris_session_list.json", methods=("closure", "ferraris")),
    "imucal-annotated": Case("imucal/annotated_session.csv", fs=204.8, gyro_counts=16.4, accel_counts=2048.0,
                             protocol="ferraris", methods=("closure", "paper")),
    "imu_tk": Case("imu_tk/xsens_gyro.mat", accel_file="imu_tk/xsens_acc.mat"),
    "imu_tk-sensitivities": Case("imu_tk/xsens_gyro.mat", accel_file="imu_tk/xsens_acc.mat", gyro_counts=109.2,
                                 accel_counts=3724.0),
    "sunsided-uniform": Case("sunsided/sunsided_xyz_uniform.csv"),
    "sunsided-hosttime": Case("sunsided/sunsided_xyz_hosttime.csv"),
}
SIMULATED = {
    "simulated-paper": Case("paper.csv", methods=("closure", "paper")),
    "simulated-ferraris": Case("ferraris.csv", protocol="ferraris", methods=("closure", "ferraris")),
    "simulated-multi-position": Case("multi-position.csv"),
    # turned about y only (twice): y is calibrated, x and z are named as not determined, through every door
    "simulated-partial": Case("partial.csv"),
}


@pytest.fixture(scope="module")
def recordings(real_data: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Where each case's files are: the real recordings as they are, the simulated ones written once."""
    from calib.io.readers import write_native_csv
    from calib.simulator import ProtocolScript, Still, Turn, simulate
    from calib.simulator.lab_scripts import ferraris_script, multi_position_script, with_accelerometer_error

    folder = tmp_path_factory.mktemp("simulated")
    paper, _ = simulate(3, noise=0.03)
    ferraris, _ = simulate(4, noise=0.03, script=ferraris_script(np.random.default_rng(4)))
    rng = np.random.default_rng(5)
    multi, _ = simulate(5, noise=0.05, fs=100.0, script=multi_position_script(rng, n=12, first_rest_s=20.0), accel_noise_g=0.005)
    multi, _ = with_accelerometer_error(multi, rng)
    partial, _ = simulate(6, noise=0.03, script=ProtocolScript((Still(3.0), Turn("y", 360.0), Still(3.0), Turn("y", 360.0), Still(3.0))))
    for name, rec in (("paper.csv", paper), ("ferraris.csv", ferraris), ("multi-position.csv", multi), ("partial.csv", partial)):
        write_native_csv(rec, folder / name)
    return {"real": real_data, "simulated": folder}


def _where(recordings: dict[str, Path], name: str) -> Path:
    return recordings["simulated" if name in SIMULATED else "real"]


def _case(name: str) -> Case:
    return {**REAL, **SIMULATED}[name]


def by_cli(case: Case, root: Path, method: str) -> dict[str, Any]:
    """``gyrocal calibrate --json`` in this process: its result, or {"refused": code, "message": ...}."""
    args = ["calibrate", str(root / case.file), "--json", "--method", method, "--protocol", case.protocol]
    args += ["--fs", str(case.fs)] if case.fs else []
    args += ["--gyro-counts-per-dps", str(case.gyro_counts)] if case.gyro_counts else []
    args += ["--accel-counts-per-g", str(case.accel_counts)] if case.accel_counts else []
    args += ["--layout", "imu_tk", "--accel", str(root / case.accel_file)] if case.accel_file else []
    args += ["--sections", str(root / case.sections)] if case.sections else []
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = gyrocal(args)
    printed = json.loads(out.getvalue())
    if code != 0:
        assert "error" in printed, err.getvalue()
        return {"refused": printed["error"]["code"], "message": printed["error"]["message"]}
    return printed


def by_api(service: Any, case: Case, root: Path, device: str, method: str) -> dict[str, Any]:
    """``POST /devices/{id}/calibrate``: its result, or {"refused": code, "message": detail}."""
    query: dict[str, Any] = {"method": method, "protocol": case.protocol}
    query |= {"fs": case.fs} if case.fs else {}
    query |= {"gyro_counts_per_dps": case.gyro_counts} if case.gyro_counts else {}
    query |= {"accel_counts_per_g": case.accel_counts} if case.accel_counts else {}
    query |= {"sections": (root / case.sections).read_text()} if case.sections else {}
    with api(service) as c:
        if case.accel_file:
            files = {"gyro": (root / case.file).read_bytes(), "accel": (root / case.accel_file).read_bytes()}
            r = c.post(f"/devices/{device}/calibrate", params={**query, "layout": "imu_tk"}, files=files, timeout=120)
        else:
            r = c.post(f"/devices/{device}/calibrate", params=query, content=(root / case.file).read_bytes(),
                       headers={"Content-Type": "text/csv"}, timeout=120)
    if r.status_code != 200:
        assert r.status_code in (400, 422), r.text
        return {"refused": r.json()["code"], "message": r.json()["detail"]}
    return r.json()


def by_page(wizard: Wizard, page: Any, service: Any, case: Case, root: Path, device: str) -> dict[str, Any]:
    """The page's upload form, as a clinician fills it: the stored result of the session it opens, or the refusal it
    shows."""
    page.goto(service.base + "/#/upload")
    page.wait_for_selector("form.upload-form")
    page.fill("#up-device", device)
    page.set_input_files("#up-file", str(root / case.file))
    if case.accel_file:
        page.set_input_files("#up-accel-file", str(root / case.accel_file))
    if case.sections:
        page.set_input_files("#up-sections", str(root / case.sections))
    page.select_option("#up-protocol", case.protocol)
    for selector, value in (("#up-fs", case.fs), ("#up-gyro-counts", case.gyro_counts), ("#up-accel-counts", case.accel_counts)):
        if value:
            page.fill(selector, str(value))
    page.click("form.upload-form button[type=submit]")
    status = page.locator("form.upload-form [role=status]")
    page.wait_for_function("""() => location.hash.startsWith('#/session/') || !['', 'Calibrating the recording…'].includes(
                               document.querySelector('form.upload-form [role=status]').textContent)""", timeout=120_000)
    if not page.url.split("#")[-1].startswith("/session/"):
        return {"shown": status.inner_text()}
    sid = page.url.rsplit("/", 1)[1]
    verdict = page.locator(".verdict h1").inner_text()
    sentence = page.locator("p.sentence").first.inner_text()
    page.click("details.details summary")
    with api(service) as c:
        return c.get(f"/sessions/{sid}").json()["result"] | {"table": page.locator("table.params").inner_text(),
                                                              "verdict": verdict, "sentence": sentence}


def assert_same(a: dict[str, Any], b: dict[str, Any], what: str) -> None:
    for p in PARAMETERS:
        assert (a.get(p) is None) == (b.get(p) is None), f"{what}: {p}"
        if a.get(p) is not None:
            np.testing.assert_allclose(np.asarray(a[p], float), np.asarray(b[p], float), rtol=0, atol=1e-12, err_msg=f"{what}: {p}")
    assert a["method"] == b["method"] and a["quality"]["protocol"]["used"] == b["quality"]["protocol"]["used"], what


@pytest.mark.timeout(240)
@pytest.mark.parametrize("name", [*REAL, *SIMULATED])
def test_the_command_line_the_api_and_the_page_give_one_calibration(name: str, recordings: dict[str, Path], webui_service: Any,
                                                                     wizard: Wizard, page: Any) -> None:
    case, root = _case(name), _where(recordings, name)
    for method in case.methods:
        cli = by_cli(case, root, method)
        served = by_api(webui_service, case, root, f"door-{name}-{method}", method)
        if "refused" in cli:
            assert served == cli, f"{name} ({method}): the CLI refused with {cli}, the API answered {served}"
        else:
            assert "refused" not in served, f"{name} ({method}): the CLI calibrated, the API refused: {served}"
            assert_same(cli, served, f"{name} ({method}), CLI against API")
    wizard.sign_in()
    shown = by_page(wizard, page, webui_service, case, root, f"door-{name}-page")
    cli = by_cli(case, root, "closure")
    if "refused" in cli:
        assert shown.get("shown") == cli["message"], f"{name}: the page showed {shown}"
    else:
        assert "shown" not in shown, f"{name}: the page refused what the CLI calibrated: {shown['shown']}"
        assert_same(cli, shown, f"{name}, CLI against the page")
        assert f"{next(k for k in cli['k'] if k is not None):.5f}" in shown["table"]  # what the page shows is that result
        missing = cli["quality"].get("undetermined_axes") or []
        assert (shown["verdict"] == "INCOMPLETE") == bool(missing), shown["verdict"]
        assert shown["table"].count("not determined") == 2 * len(missing), shown["table"]
        if missing:
            assert missing == ["x", "z"] and shown["sentence"].endswith("no usable full turn about X and Z, so their "
                                                                        "scale factors are not determined."), shown["sentence"]
