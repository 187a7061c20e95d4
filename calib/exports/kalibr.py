"""Kalibr's IMU configuration (``imu.yaml``, the ``--imu`` file of ``kalibr_calibrate_imu_camera``) from a rest's noise.

Kalibr's noise model (its wiki, "IMU Noise Model", github.com/ethz-asl/kalibr/wiki/IMU-Noise-Model) is, per axis, a
continuous-time white noise of strength sigma (``*_noise_density``: rad/s/sqrt(Hz) for the gyroscope, m/s^2/sqrt(Hz)
for the accelerometer) and a bias driven by white noise of strength sigma_b (``*_random_walk``: rad/s^2/sqrt(Hz),
m/s^3/sqrt(Hz)), one value for all three axes, with ``update_rate`` (Hz) to discretise them and ``rostopic``. Its
Allan variance is sigma^2 / tau + sigma_b^2 tau / 3: sigma is gyrocal's noise density N, sigma_b its random walk K,
converted from deg/s to rad/s and from g to m/s^2 (9.80665). Per axis the largest of the three is written (Kalibr
takes one); a random walk the rest did not show is written as its 95 % upper bound, and the file says so.
"""

from __future__ import annotations

from calib.errors import GyrocalError
from calib.noise.analysis import AxisNoise, NoiseReport
from calib.units import DEG, STANDARD_GRAVITY


def _largest(axes: tuple[AxisNoise, ...], which: str, scale: float) -> tuple[float, str]:
    readings = [getattr(a, which) for a in axes]
    value = max(r.shown for r in readings) * scale
    unseen = [a.axis for a, r in zip(axes, readings, strict=True) if not r.seen]
    note = "" if not unseen else f"  # axes {','.join(unseen)}: not seen in the rest, their 95 % upper bound"
    return value, note


def kalibr_imu_yaml(report: NoiseReport, topic: str = "/imu0", rate_hz: float | None = None) -> str:
    """Kalibr's imu.yaml for the sensor whose rest ``report`` analysed (GyrocalError when it has no accelerometer:
    Kalibr needs both sensors' noise)."""
    if report.accel is None:
        raise GyrocalError("Kalibr's imu.yaml needs the accelerometer's noise too, and this rest has no accelerometer columns; "
                           "record the rest with the accelerometer")
    rate = report.sample_rate_hz if rate_hz is None else rate_hz
    an, an_note = _largest(report.accel, "density", STANDARD_GRAVITY)
    ak, ak_note = _largest(report.accel, "random_walk", STANDARD_GRAVITY)
    gn, gn_note = _largest(report.gyro, "density", DEG)
    gk, gk_note = _largest(report.gyro, "random_walk", DEG)
    return (f"# Kalibr IMU configuration from gyrocal's Allan analysis of {report.source or 'a rest'} "
            f"({report.duration_s:.0f} s at {report.sample_rate_hz:g} Hz); the largest of the three axes\n"
            "#Accelerometers\n"
            f"accelerometer_noise_density: {an:.6e}   # [ m / s^2 / sqrt(Hz) ]{an_note}\n"
            f"accelerometer_random_walk: {ak:.6e}     # [ m / s^3 / sqrt(Hz) ]{ak_note}\n"
            "#Gyroscopes\n"
            f"gyroscope_noise_density: {gn:.6e}       # [ rad / s / sqrt(Hz) ]{gn_note}\n"
            f"gyroscope_random_walk: {gk:.6e}         # [ rad / s^2 / sqrt(Hz) ]{gk_note}\n"
            f"rostopic: {topic}\n"
            f"update_rate: {rate:g}   # Hz\n")
