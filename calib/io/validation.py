"""Plausibility checks for a Recording; every failure names the sample and channel and says how to fix it."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from calib.errors import RecordingError
from calib.recording import Recording

MAX_GYRO_DPS = 10_000.0  # beyond the range of any MEMS gyroscope
MAX_ACCEL_G = 50.0
TEMP_RANGE_C = (-60.0, 150.0)
FS_RANGE_HZ = (1.0, 10_000.0)
FS_TOLERANCE = 0.05  # a stated sample rate may differ this much (relative) from the time column

DEFAULT_COLUMNS: Mapping[str, Sequence[str]] = {
    "t": ("t",),
    "gyro": ("gyro x", "gyro y", "gyro z"),
    "accel": ("accel x", "accel y", "accel z"),
    "seq": ("seq",),
    "temp": ("temp",),
    "host_t": ("host_t",),
}


@dataclass(frozen=True)
class Locator:
    """How messages name a sample (file line or sample number) and a channel (column name)."""

    source: str | None = None
    lines: np.ndarray | None = None  # 1-based file line of each sample, when read from a file
    columns: Mapping[str, Sequence[str]] = field(default_factory=lambda: DEFAULT_COLUMNS)

    def prefix(self) -> str:
        return f"{self.source}: " if self.source else ""

    def row(self, i: int) -> str:
        if self.lines is not None:
            return f"line {int(self.lines[i])}"
        return f"sample {i + 1}"

    def column(self, channel: str, axis: int = 0) -> str:
        return self.columns[channel][axis]

    def at(self, i: int, channel: str, axis: int = 0) -> str:
        return f"{self.prefix()}{self.row(i)}, column {self.column(channel, axis)}"


def validate_recording(rec: Recording, min_duration_s: float | None = None) -> None:
    """Raise RecordingError if the recording is unusable (non-finite, out of order, absurd, too short)."""
    check_recording(rec, min_duration_s, Locator(source=rec.meta.source))


def check_recording(rec: Recording, min_duration_s: float | None = None, where: Locator | None = None) -> None:
    """validate_recording with messages located by ``where`` (file lines and column names)."""
    where = where or Locator(source=rec.meta.source)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        _check(rec, min_duration_s, where)


def _check(rec: Recording, min_duration_s: float | None, where: Locator) -> None:
    n = len(rec)
    if n < 2:
        got = "no samples" if n == 0 else "only 1 sample"
        raise RecordingError(
            f"{where.prefix()}the recording has {got}, so its sample rate cannot be determined; "
            "a recording needs at least 2 samples (the calibration protocol takes about 30 s)"
        )
    channels = [("t", rec.t.reshape(-1, 1)), ("gyro", rec.gyro)]
    optional = (("accel", rec.accel), ("temp", rec.temp), ("host_t", rec.host_t))
    channels += [(name, a.reshape(n, -1)) for name, a in optional if a is not None]
    for name, values in channels:
        check_finite(values, name, where)
    check_increasing(rec.t, "t", where, what="time")
    if rec.seq is not None:
        check_increasing(rec.seq, "seq", where, what="sample counter")
    if rec.host_t is not None and np.any(np.diff(rec.host_t) < 0):
        i = int(np.flatnonzero(np.diff(rec.host_t) < 0)[0]) + 1
        raise RecordingError(
            f"{where.at(i, 'host_t')}: the host receive time goes backwards ({rec.host_t[i - 1]:g} then "
            f"{rec.host_t[i]:g} s); host_t must be the host clock at arrival, in s, in row order"
        )
    check_magnitude(rec.gyro, "gyro", MAX_GYRO_DPS, "deg/s", where, "is the column in deg/s (not mdps, rad/s or raw counts)?")
    if rec.accel is not None:
        check_magnitude(rec.accel, "accel", MAX_ACCEL_G, "g", where, "is the column in g (not m/s^2, mg or raw counts)?")
    if rec.temp is not None:
        lo, hi = TEMP_RANGE_C
        bad = np.flatnonzero((rec.temp < lo) | (rec.temp > hi))
        if bad.size:
            i = int(bad[0])
            raise RecordingError(
                f"{where.at(i, 'temp')}: temperature {rec.temp[i]:g} C is outside {lo:g}..{hi:g} C; "
                "is the column in degrees Celsius? Remove the temp column if it holds something else"
            )
    check_rate(rec, where)
    if min_duration_s is not None and rec.duration_s < min_duration_s:
        raise RecordingError(
            f"{where.prefix()}the recording lasts {rec.duration_s:.1f} s but the protocol needs at least "
            f"{min_duration_s:g} s (rest about 3 s, then turn the device 360 deg about x, y and z with pauses); "
            "record the whole protocol again"
        )


def check_finite(values: np.ndarray, channel: str, where: Locator) -> None:
    """Reject NaN and infinite values, naming the first one."""
    if np.isfinite(values.sum()):  # the common case, at a fraction of the search's cost (a huge sum is searched)
        return
    bad = np.argwhere(~np.isfinite(values))
    if bad.size:
        i, j = (int(v) for v in bad[0])
        raise RecordingError(
            f"{where.at(i, channel, j)}: value {values[i, j]} is not a finite number; "
            "remove or repair the row (NaN and inf are not accepted)"
        )


def check_increasing(values: np.ndarray, channel: str, where: Locator, what: str) -> None:
    """Reject duplicate and backwards steps in a time or counter column, naming the first one."""
    steps = np.diff(values)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        kind = "repeats" if steps[i - 1] == 0 else "goes backwards from"
        raise RecordingError(
            f"{where.at(i, channel)}: the {what} {kind} the previous row's value "
            f"({values[i - 1]:g} -> {values[i]:g}); it must strictly increase, so sort the rows by "
            f"{where.column(channel)} and remove duplicated rows"
        )


def check_magnitude(values: np.ndarray, channel: str, limit: float, unit: str, where: Locator, hint: str) -> None:
    """Reject readings beyond what any sensor of this kind can report."""
    if values.size and -limit <= values.min() and values.max() <= limit:
        return
    bad = np.argwhere(np.abs(values) > limit)
    if bad.size:
        i, j = (int(v) for v in bad[0])
        raise RecordingError(
            f"{where.at(i, channel, j)}: {values[i, j]:g} {unit} is beyond any sensor's range "
            f"(limit +-{limit:g} {unit}); {hint}"
        )


def check_rate(rec: Recording, where: Locator) -> None:
    """The stated and the measured sample rate must be plausible and agree."""
    lo, hi = FS_RANGE_HZ
    stated = rec.meta.sample_rate_hz
    if stated is not None:
        check_sample_rate(stated, where.prefix())
    step = rec.median_step_s
    measured = 1.0 / step
    if stated is None and not lo <= measured <= hi:
        hint = "is t in milliseconds or microseconds? It must be in seconds" if measured < lo else "is t in seconds?"
        raise RecordingError(
            f"{where.prefix()}column {where.column('t')}: the median time step is {step:g} s, i.e. {measured:g} Hz, "
            f"outside the plausible {lo:g}..{hi:g} Hz; {hint}"
        )
    if stated is not None and abs(measured - stated) > FS_TOLERANCE * stated:
        raise RecordingError(
            f"{where.prefix()}the sample rate was given as {stated:g} Hz but the time column "
            f"{where.column('t')} has a median step of {step:g} s ({measured:g} Hz); "
            "pass the device's real rate or leave fs out to use the time column"
        )


def check_sample_rate(fs: object, prefix: str = "") -> float:
    """A stated sample rate as a float, or RecordingError if it is not a plausible rate in Hz."""
    lo, hi = FS_RANGE_HZ
    try:
        value = float(fs)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise RecordingError(f"{prefix}sample rate {fs!r} is not a number; give fs in Hz, e.g. 104") from None
    if not lo <= value <= hi:
        raise RecordingError(
            f"{prefix}sample rate {value:g} Hz is outside the plausible {lo:g}..{hi:g} Hz; give fs in Hz, e.g. 104"
        )
    return value


def check_calibration_input(rec: object) -> None:
    """What every estimator asks of its input: a valid Recording (see validate_recording)."""
    if not isinstance(rec, Recording):
        raise RecordingError(f"expected a Recording, got {type(rec).__name__}: read files with calib.io.readers.read_recording")
    validate_recording(rec)
