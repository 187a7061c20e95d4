"""A recording whose full turns are about some of the device's axes only: which axes its turns determine, and the
closure fit's starting point with the others' scale factors at 1.

A turn determines the scale factor of an axis it is mostly about. An axis no turn is mostly about is not
determined: its scale factor starts at 1 and has a working sensor's prior in the fit (its rate in the other turns is
the hand's wobble, a few degrees, so it barely moves the others) and is reported as not determined, and so is its
bias, which is the rest's reading times that scale factor.
"""

from __future__ import annotations

import numpy as np

from calib.estimators.closure.fit import ClosureData, bias_free_angles
from calib.stages.stage import AXES
from calib.units import FULL_TURN_DEG

TURN_SHARE = 0.5  # a turn determines an axis when at least this share of its rotation is about that axis


def turned_axes(data: ClosureData) -> np.ndarray:
    """(3,) whether some turn is mostly about each axis (``TURN_SHARE`` of its rotation or more)."""
    a = np.abs(bias_free_angles(data)[0][0])
    share = a / np.maximum(np.linalg.norm(a, axis=1, keepdims=True), 1e-12)
    return np.any(share >= TURN_SHARE, axis=0)


def partial_start(data: ClosureData, turned: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start values theta (6,) with the scale factors of the axes not ``turned`` at 1, and the turn counts (J,)."""
    angles, beta = bias_free_angles(data)
    a = angles[0]
    turns = np.maximum(1.0, np.round(np.linalg.norm(a, axis=1) / FULL_TURN_DEG))
    A = a * a
    y = (FULL_TURN_DEG * turns) ** 2 - A[:, ~turned].sum(axis=1)  # the other axes at k = 1
    k2, *_ = np.linalg.lstsq(A[:, turned], y, rcond=None)
    k = np.ones(3)
    k[turned] = np.sqrt(np.maximum(k2, 1e-6))
    return np.concatenate((k, -k * beta[0])), turns


def not_turned_text(turned: np.ndarray) -> str:
    """'no usable full turn about x and z: their scale factors ... are not determined' (or the one axis)."""
    missing = [a for a, t in zip(AXES, turned, strict=True) if not t]
    if len(missing) == 1:
        return (f"no usable full turn about {missing[0]}: its scale factor (and its bias, in deg/s of true rate) is not "
                "determined")
    return (f"no usable full turn about {' and '.join(missing)}: their scale factors (and their biases, in deg/s of "
            "true rate) are not determined")
