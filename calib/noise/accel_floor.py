"""The accelerometer's noise floor: how much its rest means scatter beyond white noise.

A MEMS accelerometer's output wanders slowly (flicker, bias instability): averaging a rest for seconds brings
its white noise down as 1/sqrt(n), but not this part, which levels off. Measured on the longest rest, axis by
axis: cut it into spans as long as a typical rest, and compare the spread of the spans' means with what white
noise of the rest's per-sample spread (its colour counted) gives them. Where the spread is beyond chance
(``FLOOR_ALPHA``), the excess variance is the floor; every rest's mean is that much less certain.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from calib.distributions import chi2_isf

FLOOR_ALPHA = 0.01  # chance that white noise alone shows a floor on an axis
MIN_SPANS = 4  # the longest rest must hold this many spans of a typical rest's length


@dataclass(frozen=True)
class AccelFloor:
    """Per raw axis, the scatter of a rest's mean beyond white noise (g); zero where none is measured."""

    sd: np.ndarray  # (3,) g
    tau_s: float  # the span it is measured over (a typical rest's length), s
    ratio: np.ndarray | None  # (3,) spread of the spans' means over white noise's (variance ratio); None: not measured
    rest: int | None  # the rest it is measured on

    @property
    def measured(self) -> bool:
        """Whether a rest was long enough to measure it."""
        return self.ratio is not None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: per axis in mg, with the spread ratio and where it was measured."""
        return {"measured": self.measured, "per_axis_mg": [float(v) for v in 1000.0 * self.sd],
                "tau_s": self.tau_s, "rest": self.rest,
                "variance_ratio": None if self.ratio is None else [float(v) for v in self.ratio]}


NO_FLOOR = AccelFloor(np.zeros(3), 0.0, None, None)


def accel_floor(accel: np.ndarray, spans: list[tuple[int, int]], colour: np.ndarray, fs: float) -> AccelFloor:
    """The floor of ``accel`` (n, 3) g measured on the longest of the rests ``spans`` ([i, j) samples) over the
    median rest's length; ``colour`` (3,) the white noise's colour (``calib.noise.rests.noise_colour``).
    Not measured (zero) when no rest holds ``MIN_SPANS`` spans."""
    lengths = np.array([j - i for i, j in spans])
    if lengths.size == 0:
        return NO_FLOOR
    n = max(int(np.median(lengths)), 2)
    longest = int(np.argmax(lengths))
    M = int(lengths[longest] // n)
    if M < MIN_SPANS:
        return NO_FLOOR
    i = spans[longest][0]
    spans_of = accel[i : i + M * n].reshape(M, n, 3)
    means = spans_of.mean(axis=1)
    white = spans_of.var(axis=1).mean(axis=0) * np.asarray(colour) / n  # a span mean's white part
    ratio = np.var(means, axis=0, ddof=1) / np.maximum(white, 1e-300)
    beyond = ratio > chi2_isf(FLOOR_ALPHA, M - 1) / (M - 1)
    sd = np.where(beyond, np.sqrt(np.maximum(ratio - 1.0, 0.0) * white), 0.0)
    return AccelFloor(sd, n / fs, ratio, longest)
