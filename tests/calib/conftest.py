"""Real sessions shared by the numerics' tests, read once per test process."""

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


# what the diagnosis names in the untouched session, as docs/real-data.md describes it: its own physics
IMU_TK_OWN_EFFECTS = frozenset({"bias_instability", "axis_misalignment", "g_sensitivity", "scale_asymmetry"})


# with 20 replicates (the tests' few) the untouched session also names a borderline bias drift (p 0.0044); with 50
# or the default 200 it does not
IMU_TK_OWN_EFFECTS_20 = IMU_TK_OWN_EFFECTS | {"bias_drift"}


@pytest.fixture(scope="session")
def imu_tk_own_effects_20() -> frozenset[str]:
    """What the untouched session names when diagnosed with 20 replicates: its own effects and a borderline drift."""
    return IMU_TK_OWN_EFFECTS_20
