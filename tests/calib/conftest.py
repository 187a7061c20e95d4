"""Real sessions shared by the numerics' tests, read and diagnosed once per test process."""

from __future__ import annotations

from pathlib import Path

import pytest

from calib.recording import Recording


@pytest.fixture(scope="session")
def imu_tk_session(real_data: Path) -> Recording:
    """imu_tk's Xsens session (multi-position, 100 Hz, 512 s), at imu_tk's nominal scales."""
    from calib.io.imu_tk import read_imu_tk

    where = real_data / "imu_tk"
    return read_imu_tk(where / "xsens_gyro.mat", where / "xsens_acc.mat")


@pytest.fixture(scope="session")
def imu_tk_own_effects(imu_tk_session: Recording) -> set[str]:
    """What the diagnosis (20 replicates) names in the untouched session: its own physics."""
    from calib.diagnosis import diagnose

    return {e["name"] for e in diagnose(imu_tk_session, n_boot=20).effects}
