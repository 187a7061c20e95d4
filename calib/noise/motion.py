"""The gyroscope's noise while it moves, against its noise at rest.

A MEMS gyroscope can be noisier while it turns than while it rests (its proof mass shaken by the hand, noise that
grows with the rate); the rotation integrated over a motion then scatters more than the rests' noise predicts.
Below a few tens of hertz the motion itself hides the noise, but the top of the band is (almost) empty of hand
motion: there, the readings' power during the motions over their power during the rests is the noise's variance
ratio, if the noise is white. Measured axis by axis in the top tenth of the band (``BAND``, a fraction of the
Nyquist frequency), with an F test at ``MOTION_NOISE_ALPHA``; counted (each motion's noise scaled by it) only
where it is beyond chance. A knock (the device put down) reaches the top band as a burst far above the noise: its
samples are left out of the power (``KNOCK_SIGMA``), which is otherwise an upper bound of the noise's. A sensor
whose own low-pass filter empties the top of the band (its rests' power there far below white noise's share) leaves
the ratio unmeasured: what is left there is not the noise that is integrated. So does a sample rate whose top band
starts below ``MIN_BAND_HZ``: a hand's motion still has power there (on imu_tk's Xsens, 20 times the noise's at
20 Hz), which would read as noise many times over.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.signal import butter, sosfiltfilt

from calib.distributions import f_sf

BAND = (0.9, 1.0)  # the band the power is compared in, as fractions of the Nyquist frequency
MOTION_NOISE_ALPHA = 0.01  # chance that white noise of one level shows a ratio on an axis
FILTER_ORDER = 8
EDGE_SAMPLES = 16  # samples the high-pass filter's response takes to die away: left out at each span's ends
MIN_BAND_HZ = 40.0  # the band's lower edge must be at least this high (a sample rate of about 89 Hz or more)
MIN_WHITE_SHARE = 0.25  # the rests' power in the band, over white noise's share of their variance, needed to measure
KNOCK_SIGMA = 7.0  # a band sample this many robust standard deviations out is a knock, not noise
KNOCK_RING = 3 * EDGE_SAMPLES  # samples on either side of a knock the high-pass filter still rings in
MIN_SAMPLES = 1000  # samples the rests and the motions must each hold for the ratio to be measured (to ~15 %)


@dataclass(frozen=True)
class MotionNoise:
    """Per axis, the gyroscope's noise variance while moving over its variance at rest, counted where beyond chance."""

    ratio: np.ndarray | None  # (3,) measured variance ratio; None: not measured
    counted: np.ndarray  # (3,) the factor the motions' noise variance is scaled by (1 where not counted)
    p_value: np.ndarray | None  # (3,) chance of a ratio that large from noise of one level
    band_hz: tuple[float, float]
    reason: str = ""  # why it was not measured

    @property
    def measured(self) -> bool:
        """Whether the rests and motions were long enough to measure it."""
        return self.ratio is not None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the band, the measured ratios, their p-values and the factors counted."""
        return {"measured": self.measured, "band_hz": [float(v) for v in self.band_hz],
                "variance_ratio": None if self.ratio is None else [float(v) for v in self.ratio],
                "p_value": None if self.p_value is None else [float(v) for v in self.p_value],
                "counted": [float(v) for v in self.counted], "reason": self.reason or None}


def no_motion_noise(fs: float, reason: str = "not measured") -> MotionNoise:
    """Nothing measured (``reason`` says why): the motions' noise is the rests'."""
    return MotionNoise(None, np.ones(3), None, (BAND[0] * fs / 2, BAND[1] * fs / 2), reason)


def motion_noise(gyro: np.ndarray, rests: list[tuple[int, int]], motions: list[tuple[int, int]], fs: float) -> MotionNoise:
    """The ratio for ``gyro`` (n, 3) deg/s sampled at ``fs`` Hz, with the rests and the motions as [i, j) spans."""
    if BAND[0] * fs / 2 < MIN_BAND_HZ:
        return no_motion_noise(fs, f"at {fs:g} Hz the top of the band ({BAND[0] * fs / 2:.0f}-{fs / 2:.0f} Hz) still holds the "
                                   f"hand's motion; it needs {2 * MIN_BAND_HZ / BAND[0]:.0f} Hz or more")
    top = high_band(gyro)
    power_r, n_r = _band_power(top, rests)
    power_m, n_m = _band_power(top, motions)
    if min(n_r, n_m) < MIN_SAMPLES:
        return no_motion_noise(fs, f"the rests and the motions must each hold {MIN_SAMPLES} samples")
    if np.any(power_r < MIN_WHITE_SHARE * (BAND[1] - BAND[0]) * _rest_variance(gyro, rests)):
        return no_motion_noise(fs, "the sensor's own low-pass filter empties the top of its band")
    ratio = power_m / np.maximum(power_r, 1e-300)
    width = BAND[1] - BAND[0]  # a band this wide holds this share of the samples' independent values
    dof_m, dof_r = max(width * n_m, 1.0), max(width * n_r, 1.0)
    p_value = f_sf(ratio, dof_m, dof_r)
    counted = np.where((p_value < MOTION_NOISE_ALPHA) & (ratio > 1.0), ratio, 1.0)
    return MotionNoise(ratio, counted, p_value, (BAND[0] * fs / 2, BAND[1] * fs / 2))


def high_band(readings: np.ndarray) -> np.ndarray:
    """``readings`` (n, 3) high-passed to ``BAND`` (zero phase)."""
    sos = butter(FILTER_ORDER, BAND[0], btype="highpass", output="sos")
    return sosfiltfilt(sos, readings, axis=0)


def _rest_variance(gyro: np.ndarray, rests: list[tuple[int, int]]) -> np.ndarray:
    """Per axis, the readings' variance about each rest's own mean, over all rests."""
    dev = np.concatenate([gyro[i:j] - gyro[i:j].mean(axis=0) for i, j in rests if j > i])
    return np.mean(dev**2, axis=0)


def _band_power(top: np.ndarray, spans: list[tuple[int, int]]) -> tuple[np.ndarray, int]:
    """Mean power per axis of ``top`` over the spans (their filter edges left out) and the samples it is taken over.

    A knock (the device put down, ``calib.effects.impacts``) is a burst far above the band's noise: samples beyond
    ``KNOCK_SIGMA`` robust standard deviations (from the median absolute value), and the filter's ring around them,
    are left out, so that one knock does not read as every motion's noise."""
    parts = [(i + EDGE_SAMPLES, j - EDGE_SAMPLES) for i, j in spans if j - i > 2 * EDGE_SAMPLES]
    if not parts:
        return np.zeros(3), 0
    x = np.concatenate([top[i:j] for i, j in parts])
    scale = 1.4826 * np.median(np.abs(x), axis=0)
    burst = np.any(np.abs(x) > KNOCK_SIGMA * np.maximum(scale, 1e-300), axis=1)
    if burst.any():  # widened by the filter's response on either side
        burst = np.convolve(burst.astype(float), np.ones(2 * KNOCK_RING + 1), mode="same") > 0
    keep = x[~burst]
    return np.mean(keep**2, axis=0) if keep.size else np.zeros(3), int(keep.shape[0])
