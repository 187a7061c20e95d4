"""The Recording type: what one wearable recorded, in gyrocal's units.

Units and conventions (see docs/method.md):
- ``t``: sample times in seconds, strictly increasing.
- ``gyro``: the raw gyroscope readings m in deg/s, shape (n, 3), body axes x, y, z.
- ``accel``: accelerometer in g (1 g = 9.80665 m/s^2), shape (n, 3), or None.
- ``seq``: the device's sample counter (unwrapped, one step per sample), or None.
- ``temp``: sensor temperature in degrees Celsius, or None.
- ``host_t``: when each sample reached the host, in s of the host's clock, or None. ``t`` is the
  device's own clock; comparing the two reveals a device clock that runs fast or slow.
"""

from __future__ import annotations

import builtins
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np

from calib.io.section import Section


@dataclass(frozen=True)
class RecordingMeta:
    """What is known about the device and the recording, beyond the samples."""

    sample_rate_hz: float | None = None  # nominal rate if the device states one
    device_id: str | None = None
    sensor_model: str | None = None
    gyro_full_scale_dps: float | None = None  # readings at +-this value are clipped
    source: str | None = None  # file name or stream name, for messages
    sections: tuple[Section, ...] = ()  # labelled sections the file carries (imucal's ``part`` column)
    # relative standard error of the rate the times were placed at, when it was estimated (from arrival times): every
    # angle, so every scale factor, shares it
    sample_rate_rel_std: float | None = None


def fixed_rate_instants(t: np.ndarray, tolerance: float = 0.6) -> np.ndarray | None:
    """The instants of samples taken at a fixed rate but time-stamped by another clock (a host's, quantised or
    jittered): the least-squares uniform grid through ``t``, when every stamp lies within ``tolerance`` of a period
    of it (so no sample is missing and none doubled); None otherwise (the stamps are then all there is)."""
    if t.size < 3:
        return None
    i = np.arange(t.size, dtype=float)
    period, start = np.polyfit(i, t, 1)
    grid = start + period * i
    if period <= 0 or np.max(np.abs(t - grid)) > tolerance * period:
        return None
    return grid


def even_time_grid(t: np.ndarray) -> bool:
    """Whether the times are an exact even grid (no clock's jitter or quantisation): possibly numbered by whatever
    wrote the file, not stamped by the device, so rows lost before it was written leave no gap."""
    d = np.diff(t)
    return bool(d.size) and float(np.max(np.abs(d - np.median(d)))) <= 1e-9 * max(float(np.median(d)), 1e-12)


def sample_intervals(t: np.ndarray, median_step_s: float | None = None) -> np.ndarray:
    """The interval each sample is held for (s): t[i+1] - t[i], the last one the median interval (``median_step_s``
    when it is known). Across lost samples the last reading is held until the next one arrives."""
    d = np.diff(t)
    if not d.size:
        return np.array([1.0])
    return np.append(d, np.median(d) if median_step_s is None else median_step_s)


@dataclass(frozen=True, eq=False)
class Recording:
    """One recording: times (s), gyro readings (deg/s) and optional channels."""

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray | None = None
    seq: np.ndarray | None = None
    temp: np.ndarray | None = None
    meta: RecordingMeta = field(default_factory=RecordingMeta)
    host_t: np.ndarray | None = None

    def __post_init__(self) -> None:
        # contiguous: a column slice of a file's table would make every pass over the readings several times slower
        t = np.ascontiguousarray(self.t, dtype=float)
        gyro = np.ascontiguousarray(self.gyro, dtype=float)
        if t.ndim != 1 or gyro.shape != (t.size, 3):
            raise ValueError(f"Recording needs t of shape (n,) and gyro of shape (n, 3); got {t.shape} and {gyro.shape}")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "gyro", gyro)
        for name, width in (("accel", 3), ("seq", None), ("temp", None), ("host_t", None)):
            value = getattr(self, name)
            if value is None:
                continue
            arr = np.ascontiguousarray(value, dtype=np.int64 if name == "seq" else float)
            expected = (t.size, width) if width else (t.size,)
            if arr.shape != expected:
                raise ValueError(f"Recording.{name} must have shape {expected}, got {arr.shape}")
            object.__setattr__(self, name, arr)

    def __len__(self) -> int:
        return int(self.t.size)

    @property
    def duration_s(self) -> float:
        """Time from the first to the last sample (s)."""
        return float(self.t[-1] - self.t[0]) if len(self) > 1 else 0.0

    @property
    def fs(self) -> float:
        """Sample rate (Hz): the stated one, else the median of the sample intervals."""
        if self.meta.sample_rate_hz:
            return float(self.meta.sample_rate_hz)
        return float(1.0 / self.median_step_s)

    @cached_property
    def median_step_s(self) -> float:
        """The median of the sample intervals (s); NaN with fewer than two samples. Found once: the times are not
        changed after the recording is made."""
        return float(np.median(np.diff(self.t))) if len(self) > 1 else float("nan")

    @cached_property
    def intervals_s(self) -> np.ndarray:
        """The interval each sample is held for (s, ``sample_intervals``), read-only."""
        out = sample_intervals(self.t, self.median_step_s)
        out.flags.writeable = False
        return out

    @property
    def loss_visible(self) -> bool:
        """Whether lost samples would show: there is a sample counter, or the times are not an exact even grid (a
        device's or host's stamps leave a gap where samples are missing; a grid a file writer numbered does not)."""
        return self.seq is not None or not even_time_grid(self.t)

    @property
    def mean_temperature_c(self) -> float | None:
        """The sensor's mean temperature over the recording (degC, to 0.01), None without a temperature channel."""
        if self.temp is None or not np.isfinite(self.temp).any():
            return None
        return round(float(np.nanmean(self.temp)), 2)

    def slice(self, start: int, end: int) -> Recording:
        """Samples start..end-1 as a new Recording with the same metadata."""
        return self.select(np.s_[start:end])

    def select(self, rows: np.ndarray | builtins.slice) -> Recording:
        """The samples where ``rows`` (a boolean mask, indices or a slice) picks them, as a new Recording with the same
        metadata; the sample counter keeps its values, so the samples left out show as lost."""
        pick = lambda a: None if a is None else a[rows]  # noqa: E731
        return Recording(self.t[rows], self.gyro[rows], pick(self.accel), pick(self.seq), pick(self.temp), self.meta,
                         pick(self.host_t))

    def timed_by_counter(self, fs_hz: float, rel_std: float | None = None) -> Recording:
        """A copy whose times are the sample counter over ``fs_hz`` (from the first sample's time): for
        devices that send no time stamps, whose sample times were placed live from arrival times with a rate
        estimate that improved as the session went on. ``rel_std``: that estimate's relative standard error,
        kept in the metadata. Needs ``seq``."""
        if self.seq is None or not fs_hz > 0:
            raise ValueError("timing by the sample counter needs a counter and a positive rate")
        t = self.t[0] + (self.seq - self.seq[0]) / fs_hz if len(self) else self.t
        return replace(self, t=t, meta=replace(self.meta, sample_rate_hz=float(fs_hz), sample_rate_rel_std=rel_std))

    def with_meta(self, **changes: Any) -> Recording:
        """A copy with some metadata fields replaced."""
        return replace(self, meta=replace(self.meta, **changes))
