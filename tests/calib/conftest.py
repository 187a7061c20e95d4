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


@pytest.fixture(scope="session")
def imu_tk_own_effects() -> frozenset[str]:
    """The untouched session's own effects (docs/real-data.md; ``bench/diagnosis_real.py`` diagnoses it afresh)."""
    return IMU_TK_OWN_EFFECTS
