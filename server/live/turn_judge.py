"""Whether a closed motion is the turn that was asked for, and if not, what to tell the clinician.

Pure functions of what was measured (``TurnMeasure``, from server.live.stream) and the tolerances;
the session applies the verdict (retry or fail).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.judge.acceptance import Tolerances
from calib.stages.stage import AXES
from calib.units import FULL_TURN_DEG

from . import firmware_guidance as firmware_says
from . import guidance as say
from .codes import EndReason


@dataclass(frozen=True)
class TurnMeasure:
    """A closed motion as measured on the raw readings."""

    angles: np.ndarray  # (3,) integrated angle about x, y, z, deg
    saturated: bool  # the readings reached the gyro's range
    lost: int  # samples lost on the link during the motion
    gravity_deg: float | None  # gravity's direction change from the rest before to the rest after (None without accelerometer)
    true_angle_deg: float | None = None  # the angle about the asked axis through the device's accepted calibration, if any
    duration_s: float | None = None  # how long the motion took
    refused: int = 0  # samples missing from the motion because the wearable sent their packets malformed


# With an accepted calibration the angle is known in true degrees, up to the power-up change of k since (about
# 1 %): a turn this far from a full one was not one, even where the raw range (k 0.78-1.24) would let it pass.
CALIBRATED_TURN_TOL_DEG = 25.0


def is_no_turn(angles: np.ndarray, tol: Tolerances) -> bool:
    """A motion too small to be any turn (a fidget)."""
    return float(np.abs(angles).max()) < 0.5 * tol.turn_angle_min_deg


def judge_turn(axis: str, m: TurnMeasure, tol: Tolerances, full_scale_dps: float | None, retry: bool) -> tuple[EndReason, str] | None:
    """None when the motion is a full turn about ``axis`` within the tolerances; else the reason and the words for it."""
    angles = m.angles
    k_got = int(np.argmax(np.abs(angles)))
    got = AXES[k_got]
    k_exp = AXES.index(axis)
    a = float(angles[k_exp])
    off_axis = float(np.hypot(*np.delete(angles, k_exp)))
    if m.refused:  # the wearable's firmware, before the radio: a turn with both gaps is named for the one it can fix
        return EndReason.UNREADABLE_DATA, firmware_says.refused_in_turn(axis, m.refused, retry)
    if m.lost:
        return EndReason.SAMPLE_LOSS, say.sample_loss(axis, m.lost, retry)
    if m.saturated:
        return EndReason.TOO_FAST, say.too_fast(axis, full_scale_dps, retry, m.duration_s)
    if got != axis and abs(angles[k_got]) >= 0.5 * tol.turn_angle_min_deg:
        return EndReason.WRONG_AXIS, say.wrong_axis(axis, got, retry)
    if abs(a) < tol.turn_angle_min_deg:
        return EndReason.TURN_INCOMPLETE, say.turn_incomplete(axis, a, retry)
    if abs(a) > tol.turn_angle_max_deg:
        return EndReason.TURN_TOO_FAR, say.turn_too_far(axis, a, retry)
    if m.true_angle_deg is not None and abs(abs(m.true_angle_deg) - FULL_TURN_DEG) > CALIBRATED_TURN_TOL_DEG:
        short = abs(m.true_angle_deg) < FULL_TURN_DEG
        code = EndReason.TURN_INCOMPLETE if short else EndReason.TURN_TOO_FAR
        return code, (say.turn_incomplete if short else say.turn_too_far)(axis, m.true_angle_deg, retry)
    if off_axis > tol.off_axis_max_fraction * abs(a):
        return EndReason.WRONG_AXIS, say.not_one_axis(axis, off_axis, retry)
    if m.gravity_deg is not None and m.gravity_deg > tol.gravity_closure_max_deg:
        return EndReason.TURN_INCOMPLETE, say.not_back(axis, m.gravity_deg, retry)
    if m.gravity_deg is not None and m.gravity_deg > tol.placement_max_deg:
        return EndReason.TURN_INCOMPLETE, say.ended_off(axis, m.gravity_deg, retry)
    return None
