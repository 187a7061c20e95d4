"""GATT UUIDs of the gyrocal wearable.

The IMU service and its characteristics use one custom 128-bit base; Device Information (0x180A)
and Battery (0x180F) are the Bluetooth SIG's standard services, written in full 128-bit form the
way BlueZ and bleak report them.
"""

from __future__ import annotations


def _custom(short: int) -> str:
    # Custom base: 7e1aXXXX-9b3c-4d2e-8f10-6779726f6361 (the node field spells "gyroca" in ASCII).
    return f"7e1a{short:04x}-9b3c-4d2e-8f10-6779726f6361"


def sig_uuid(short: int) -> str:
    """The full 128-bit form of a 16-bit Bluetooth SIG UUID."""
    return f"0000{short:04x}-0000-1000-8000-00805f9b34fb"


IMU_SERVICE = _custom(0x0001)
IMU_DATA_CHAR = _custom(0x0002)  # notify: sample packets
IMU_CONFIG_CHAR = _custom(0x0003)  # read: current configuration
IMU_CONTROL_CHAR = _custom(0x0004)  # write + notify: commands and their status replies
IMU_CALIBRATION_CHAR = _custom(0x0005)  # read: the calibration the device holds (devices that can hold one)
IMU_POWER_UP_CHAR = _custom(0x0006)  # read: boot count, uptime, temperature (devices that report them)

DEVICE_INFORMATION_SERVICE = sig_uuid(0x180A)
MANUFACTURER_NAME_CHAR = sig_uuid(0x2A29)
MODEL_NUMBER_CHAR = sig_uuid(0x2A24)
SERIAL_NUMBER_CHAR = sig_uuid(0x2A25)
FIRMWARE_REVISION_CHAR = sig_uuid(0x2A26)

BATTERY_SERVICE = sig_uuid(0x180F)
BATTERY_LEVEL_CHAR = sig_uuid(0x2A19)

CCCD_DESCRIPTOR = sig_uuid(0x2902)  # Client Characteristic Configuration
USER_DESCRIPTION_DESCRIPTOR = sig_uuid(0x2901)
