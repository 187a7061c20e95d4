"""Reader of imu_tk's ASCII recordings: gyroscope and accelerometer in separate files of raw counts.

imu_tk (Tedaldi, Pretto, Menegatti, ICRA 2014) stores each sensor as whitespace-separated rows
``t x y z``: time in s, then raw counts per axis. When the times lie within about half a sample of a fixed rate
(no sample missing), the samples are put on that rate's uniform grid: the times are then a logging clock's,
not the sensor's sampling instants. The counts become gyrocal's units with the sensor's
nominal sensitivities and zero level (for imu_tk's Xsens test data, unsigned 16-bit counts with zero
at 32768, 6258 counts per rad/s and about 3724 counts per g — the starting values of imu_tk's example
program, not a calibration).
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from calib.errors import RecordingError
from calib.recording import Recording, RecordingMeta, fixed_rate_instants

XSENS_GYRO_COUNTS_PER_RAD_S = 6258.0
XSENS_ACCEL_COUNTS_PER_G = 3724.0
XSENS_ZERO_COUNTS = 32768.0


def _table(source: Path | str, what: str, name: str) -> np.ndarray:
    """The file's rows: ``source`` a path, or the file's text (an upload) named ``name``."""
    try:
        data = np.loadtxt(io.StringIO(source) if isinstance(source, str) else source, ndmin=2)
    except (OSError, ValueError) as exc:
        raise RecordingError(f"cannot read the {what} file {name} (imu_tk's files are whitespace-separated rows 't x y z' "
                             f"of raw counts): {exc}") from None
    if data.ndim != 2 or data.shape[1] != 4 or data.shape[0] < 2:
        raise RecordingError(f"the {what} file {name} must have rows 't x y z' (4 numbers each); got shape {data.shape}")
    if not np.all(np.isfinite(data)):
        raise RecordingError(f"the {what} file {name} holds non-numbers (NaN or infinity)")
    return data


def read_imu_tk(
    gyro_path: str | Path,
    accel_path: str | Path,
    gyro_counts_per_rad_s: float = XSENS_GYRO_COUNTS_PER_RAD_S,
    accel_counts_per_g: float = XSENS_ACCEL_COUNTS_PER_G,
    zero_counts: float = XSENS_ZERO_COUNTS,
) -> Recording:
    """A Recording (gyro deg/s, accelerometer g) from imu_tk's two files, sampled at the same instants."""
    gyro_path, accel_path = Path(gyro_path), Path(accel_path)
    return _recording(_table(gyro_path, "gyroscope", str(gyro_path)), _table(accel_path, "accelerometer", str(accel_path)),
                      f"{gyro_path.name} + {accel_path.name}", gyro_counts_per_rad_s, accel_counts_per_g, zero_counts)


def parse_imu_tk(
    gyro_text: str,
    accel_text: str,
    source: str = "imu_tk upload",
    gyro_counts_per_rad_s: float = XSENS_GYRO_COUNTS_PER_RAD_S,
    accel_counts_per_g: float = XSENS_ACCEL_COUNTS_PER_G,
    zero_counts: float = XSENS_ZERO_COUNTS,
) -> Recording:
    """The same from the two files' text (an upload)."""
    return _recording(_table(gyro_text, "gyroscope", "(gyro)"), _table(accel_text, "accelerometer", "(accel)"), source,
                      gyro_counts_per_rad_s, accel_counts_per_g, zero_counts)


def _recording(g: np.ndarray, a: np.ndarray, source: str, gyro_counts_per_rad_s: float, accel_counts_per_g: float,
               zero_counts: float) -> Recording:
    if g.shape[0] != a.shape[0] or not np.allclose(g[:, 0], a[:, 0], atol=1e-3):
        raise RecordingError(
            f"the gyroscope file ({g.shape[0]} rows) and the accelerometer file ({a.shape[0]} rows) must be sampled at "
            "the same instants: give the two files of one recording")
    if gyro_counts_per_rad_s <= 0 or accel_counts_per_g <= 0:
        raise RecordingError("the sensitivities must be positive counts per rad/s and counts per g")
    t = g[:, 0] - g[0, 0]
    if np.any(np.diff(t) <= 0):
        raise RecordingError("the times in the gyroscope file must increase from row to row")
    # the files' times are the logging computer's (the Xsens test data's wander up to half a sample about the
    # device's fixed 100 Hz); integrating over them would add each stamp's error times the rate of the moment
    t = grid - grid[0] if (grid := fixed_rate_instants(t)) is not None else t
    gyro = np.degrees((g[:, 1:] - zero_counts) / gyro_counts_per_rad_s)
    accel = (a[:, 1:] - zero_counts) / accel_counts_per_g
    full_scale = float(np.degrees(zero_counts / gyro_counts_per_rad_s))
    meta = RecordingMeta(gyro_full_scale_dps=full_scale, source=source)
    return Recording(t=t, gyro=gyro, accel=accel, meta=meta)
