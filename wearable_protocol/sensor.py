"""The wearable's sensor settings: sample rates, ranges and their int16 sensitivities.

The gyro ranges and sensitivities are those of the ICM-20948 / LSM6-class parts (e.g. +-500 deg/s at
65.5 LSB per deg/s, so full scale is +-32750 counts); the accelerometer's are +-2..16 g at
16384..2048 LSB per g. Rates are the output data rates such a part offers between the paper's 104 Hz
and the ICM-20948's 562.5 Hz.
"""

from __future__ import annotations

SUPPORTED_RATES_HZ: tuple[float, ...] = (52.0, 104.0, 208.0, 416.0, 562.5)
GYRO_SENSITIVITY_LSB_PER_DPS: dict[int, float] = {250: 131.0, 500: 65.5, 1000: 32.8, 2000: 16.4}
ACCEL_SENSITIVITY_LSB_PER_G: dict[int, float] = {2: 16384.0, 4: 8192.0, 8: 4096.0, 16: 2048.0}

DEFAULT_RATE_HZ = 104.0
DEFAULT_GYRO_FULL_SCALE_DPS = 500
DEFAULT_ACCEL_RANGE_G = 4

DEFAULT_MTU = 247  # ATT MTU most centrals negotiate with a BLE 4.2+ peripheral
MAX_NOTIFICATIONS_PER_S = 40.0  # N is the fewest samples per packet that keeps the rate at or below this

INT16_MIN, INT16_MAX = -32768, 32767


def rate_supported(rate_hz: float) -> bool:
    """Whether the device offers this output data rate."""
    return any(abs(rate_hz - r) < 1e-6 for r in SUPPORTED_RATES_HZ)
