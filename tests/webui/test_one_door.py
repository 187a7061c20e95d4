"""One recording, one calibration, whichever door it comes through: every real recording of ../shared/data/real and
simulated paper, Ferraris and multi-position recordings, with the options each needs (rate, raw-count
sensitivities, imucal's section list, imu_tk's two files, a protocol), through ``gyrocal calibrate``,
``POST /devices/{id}/calibrate`` and the page's upload form in Chromium: the same k, b, K and G, or the same refusal."""

from __future__ import annotations

import contextlib
import io
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from webui_fixtures import Wizard, api

from calib.cli.main import main as gyrocal

pytestmark = pytest.mark.timeout(240)

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
    "imu_tk-as-paper": Case("imu_tk/xsens_gyro.mat", accel_file="imu_tk/xsens_acc.mat", protocol="paper"),
    "sunsided-uniform": Case("sunsided/sunsided_xyz_uniform.csv"),
    "sunsided-hosttime": Case("sunsided/sunsided_xyz_hosttime.csv"),
}
SIMULATED = {
    "simulated-paper": Case("paper.csv", methods=("closure", "paper")),
    "simulated-ferraris": Case("ferraris.csv", protocol="ferraris", methods=("closure", "ferraris")),
    "simulated-multi-position": Case("multi-position.csv"),
}


@pytest.fixture(scope="module")
def recordings(real_data: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Where each case's files are: the real recordings as they are, the simulated ones written once."""
    from calib.io.readers import write_native_csv
    from calib.simulator import simulate
    from calib.simulator.lab_scripts import ferraris_script, multi_position_script, with_accelerometer_error

    folder = tmp_path_factory.mktemp("simulated")
    paper, _ = simulate(3, noise=0.03)
    ferraris, _ = simulate(4, noise=0.03, script=ferraris_script(np.random.default_rng(4)))
    rng = np.random.default_rng(5)
    multi, _ = simulate(5, noise=0.05, fs=100.0, script=multi_position_script(rng, n=12, first_rest_s=20.0), accel_noise_g=0.005)
    multi, _ = with_accelerometer_error(multi, rng)
    for name, rec in (("paper.csv", paper), ("ferraris.csv", ferraris), ("multi-position.csv", multi)):
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
    page.wait_for_selector(".verdict h1")
    page.click("details.details summary")
    with api(service) as c:
        return c.get(f"/sessions/{sid}").json()["result"] | {"table": page.locator("table.params").inner_text()}


def assert_same(a: dict[str, Any], b: dict[str, Any], what: str) -> None:
    for p in PARAMETERS:
        assert (a.get(p) is None) == (b.get(p) is None), f"{what}: {p}"
        if a.get(p) is not None:
            np.testing.assert_allclose(np.asarray(a[p], float), np.asarray(b[p], float), rtol=0, atol=1e-12, err_msg=f"{what}: {p}")
    assert a["method"] == b["method"] and a["quality"]["protocol"]["used"] == b["quality"]["protocol"]["used"], what


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
        assert f"{cli['k'][0]:.5f}" in shown["table"]  # what the page shows is that result
