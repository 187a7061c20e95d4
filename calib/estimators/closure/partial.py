"""A recording whose full turns are about some of the device's axes only: which axes its turns determine, and the
closure fit's starting point with the others' scale factors held at 1.

A turn determines the scale factor of an axis it is mostly about. An axis no turn is mostly about is not
determined: its scale factor is held at 1 in the fit (its rate in the other turns is the hand's wobble, a few
degrees, so the value held barely matters) and reported as not determined, and so is its bias, which is the rest's
reading times that scale factor.
"""

from __future__ import annotations

import numpy as np

from calib.estimators.closure.fit import ClosureData
from calib.stages.stage import AXES
from calib.units import FULL_TURN_DEG

TURN_SHARE = 0.5  # a turn determines an axis when at least this share of its rotation is about that axis


def _bias_free_angles(data: ClosureData) -> np.ndarray:
    """Each turn's integrated reading less the rests' mean offset, (J, 3) deg, of the one recording in ``data``."""
    w = data.still_n[0][:, None]
    beta = (data.still_mean[0] * w).sum(axis=0) / max(float(w.sum()), 1.0)
    integ = np.einsum("tsi,ts->si", data.m, data.dt)
    return integ - beta * data.dt.sum(axis=0)[:, None]


def turned_axes(data: ClosureData) -> np.ndarray:
    """(3,) whether some turn is mostly about each axis (``TURN_SHARE`` of its rotation or more)."""
    a = np.abs(_bias_free_angles(data))
    share = a / np.maximum(np.linalg.norm(a, axis=1, keepdims=True), 1e-12)
    return np.any(share >= TURN_SHARE, axis=0)


def partial_start(data: ClosureData, turned: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start values theta (6,) with the scale factors of the axes not ``turned`` held at 1, and the turn counts (J,)."""
    w = data.still_n[0][:, None]
    beta = (data.still_mean[0] * w).sum(axis=0) / max(float(w.sum()), 1.0)
    a = _bias_free_angles(data)
    turns = np.maximum(1.0, np.round(np.linalg.norm(a, axis=1) / FULL_TURN_DEG))
    A = a * a
    y = (FULL_TURN_DEG * turns) ** 2 - A[:, ~turned].sum(axis=1)  # the held axes at k = 1
    k2, *_ = np.linalg.lstsq(A[:, turned], y, rcond=None)
    k = np.ones(3)
    k[turned] = np.sqrt(np.maximum(k2, 1e-6))
    return np.concatenate((k, -k * beta)), turns


def not_turned_text(turned: np.ndarray) -> str:
    """'no usable full turn about x and z: their scale factors ... are not determined' (or the one axis)."""
    missing = [a for a, t in zip(AXES, turned, strict=True) if not t]
    if len(missing) == 1:
        return (f"no usable full turn about {missing[0]}: its scale factor (and its bias, in deg/s of true rate) is not "
                "determined")
    return (f"no usable full turn about {' and '.join(missing)}: their scale factors (and their biases, in deg/s of "
            "true rate) are not determined")
