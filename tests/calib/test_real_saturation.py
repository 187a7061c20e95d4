"""Real readings clipped at a common full scale (imucal's Ferraris session, its turns peaking at 780-895 deg/s, clipped
at ±500 deg/s as a sensor with that range would): the clipped runs are 3-20 readings at exactly 500.0, shorter than
the noise rule asks of quantised readings, and used to pass in silence, moving k_z by 5.3e-3 (9 times its standard
error). A ceiling that several runs share, or a common full scale, is now taken as one."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from calib.diagnosis import diagnose
from calib.io.readers import read_recording
from calib.pipeline import calibrate_protocol
from calib.recording import Recording
from calib.stages.plateaus import find_plateaus


@pytest.fixture(scope="module")
def sessions(real_data: Path) -> tuple[Recording, Recording]:
    rec = read_recording(real_data / "imucal" / "example_ferraris_session.csv", fs=102.4)
    return rec, dataclasses.replace(rec, gyro=np.clip(rec.gyro, -500.0, 500.0))


def test_the_untouched_session_has_no_plateau(sessions: tuple[Recording, Recording]) -> None:
    rec, _ = sessions
    assert find_plateaus(rec) == []


def test_calibrate_names_the_clipped_turn_and_leaves_its_scale_factor_undetermined(
        sessions: tuple[Recording, Recording]) -> None:
    rec, clipped = sessions
    whole, _ = calibrate_protocol(rec)
    result, _ = calibrate_protocol(clipped)
    assert any("turn about z at 89.7 s reached the gyro's full scale and is not used" in w for w in result.warnings), \
        result.warnings
    assert np.isnan(result.k[2])  # not 1.0073, 5.3e-3 off in silence
    np.testing.assert_allclose(result.k[:2], whole.k[:2], atol=2e-4)  # the unclipped turns still fix k_x and k_y


def test_diagnose_names_the_saturation_and_rebuilds_the_clipped_turn(sessions: tuple[Recording, Recording]) -> None:
    rec, clipped = sessions
    whole, _ = calibrate_protocol(rec)
    found = diagnose(clipped, n_boot=20)
    named = {e["name"]: e for e in found.effects}
    assert "saturation" in named and named["saturation"]["parameters"]["full_scale_dps"] == 500.0, list(named)
    own = {e["name"] for e in diagnose(rec, n_boot=20).effects}  # the session's own (wander, placement, ...)
    assert set(named) <= own | {"saturation"}, (set(named), own)  # the flips between poses are no clipped turns
    rebuilt = found.recalibration
    assert abs(rebuilt["k"][2] - whole.k[2]) < 2.5 * rebuilt["k_std"][2], (rebuilt["k"][2], rebuilt["k_std"][2])


def test_re_orientations_clipped_at_a_common_full_scale_are_left_out_and_named(real_data: Path) -> None:
    """imu_tk's Xsens session (its counts span ±300 deg/s, the range its reader states) clipped at ±125 deg/s, as a
    sensor of that range would: before, the clipped re-orientations were used, k_y moved by 1.4e-2 (8 times its
    standard error) and nothing was said."""
    from calib.io.imu_tk import read_imu_tk

    where = real_data / "imu_tk"
    rec = read_imu_tk(where / "xsens_gyro.mat", where / "xsens_acc.mat")
    whole, _ = calibrate_protocol(rec)
    clipped = dataclasses.replace(rec, gyro=np.clip(rec.gyro, -125.0, 125.0))
    result, used = calibrate_protocol(clipped)
    assert used == "multi-position"
    said = [w for w in result.warnings if "re-orientations that reached the gyro's full scale" in w]
    assert said and said[0].startswith("9 re-orientations") and "are not used: turn more slowly" in said[0], result.warnings
    assert np.all(np.abs(np.asarray(result.k) - whole.k) < 2.5 * np.asarray(whole.k_std)), (result.k, whole.k, whole.k_std)


def test_diagnose_names_the_saturation_of_clipped_re_orientations(imu_tk_session: Recording,
                                                                  imu_tk_own_effects_20: frozenset[str]) -> None:
    """The same clipped imu_tk session diagnosed: before, the clipped re-orientations stayed in the model and their
    short rotations were put down to a scale asymmetry and a bias drift, the wrong physics."""
    found = diagnose(dataclasses.replace(imu_tk_session, gyro=np.clip(imu_tk_session.gyro, -125.0, 125.0)), n_boot=20)
    named = {e["name"]: e for e in found.effects}
    assert "saturation" in named and named["saturation"]["parameters"]["full_scale_dps"] == 125.0, list(named)
    assert named["saturation"]["parameters"]["clipped_turns"] == 9
    assert "re-orientation at" in " ".join(named["saturation"]["evidence"]["where"])
    assert set(named) <= imu_tk_own_effects_20 | {"saturation"}, (list(named), imu_tk_own_effects_20)
