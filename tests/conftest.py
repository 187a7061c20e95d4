"""Shared fixtures: where the real recordings are, and artifact output; the service's, the BLE path's and the
page's fixtures come from their own modules, registered here as plugins so every test directory sees them."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from calib.blas import single_threaded_blas

single_threaded_blas()  # as every gyrocal process runs (calib.cli.main): tests that compute in this process too

pytest_plugins = ["server_fixtures", "ble_fixtures", "webui_fixtures"]

ROOT = Path(__file__).resolve().parents[1]
REAL_DATA = Path(os.environ.get("GYROCAL_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))
ARTIFACTS = ROOT / "artifacts"


@pytest.fixture(scope="session")
def real_data() -> Path:
    """The folder of real third-party recordings (../shared/data/real)."""
    if not (REAL_DATA / "imucal" / "example_ferraris_session.csv").is_file():
        pytest.fail(f"real recordings not found at {REAL_DATA}: check out the project beside shared/ "
                    "or set GYROCAL_REAL_DATA")
    return REAL_DATA


@pytest.fixture(scope="session")
def ferraris_csv(real_data: Path) -> Path:
    """imucal's continuous Ferraris session, 102.4 Hz, accelerometer in m/s^2."""
    return real_data / "imucal" / "example_ferraris_session.csv"


@pytest.fixture(scope="session")
def artifacts() -> Path:
    """A folder for test artifacts (screenshots, plots) that CI keeps."""
    ARTIFACTS.mkdir(exist_ok=True)
    return ARTIFACTS
