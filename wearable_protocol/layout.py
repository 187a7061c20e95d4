"""The wearable's GATT database: the IMU service plus the optional standard services."""

from __future__ import annotations

from .gatt import CharacteristicSpec, ServiceSpec
from .uuids import (
    BATTERY_LEVEL_CHAR,
    BATTERY_SERVICE,
    DEVICE_INFORMATION_SERVICE,
    FIRMWARE_REVISION_CHAR,
    IMU_CALIBRATION_CHAR,
    IMU_CONFIG_CHAR,
    IMU_CONTROL_CHAR,
    IMU_DATA_CHAR,
    IMU_POWER_UP_CHAR,
    IMU_SERVICE,
    MANUFACTURER_NAME_CHAR,
    MODEL_NUMBER_CHAR,
    SERIAL_NUMBER_CHAR,
)

IMU = ServiceSpec(IMU_SERVICE, (
    CharacteristicSpec(IMU_DATA_CHAR, ("notify",), "IMU samples"),
    CharacteristicSpec(IMU_CONFIG_CHAR, ("read",), "IMU configuration"),
    CharacteristicSpec(IMU_CONTROL_CHAR, ("write", "notify"), "IMU control"),
    CharacteristicSpec(IMU_CALIBRATION_CHAR, ("read",), "Held calibration"),
    CharacteristicSpec(IMU_POWER_UP_CHAR, ("read",), "Power-up and temperature"),
))
DEVICE_INFORMATION = ServiceSpec(DEVICE_INFORMATION_SERVICE, (
    CharacteristicSpec(MANUFACTURER_NAME_CHAR, ("read",)),
    CharacteristicSpec(MODEL_NUMBER_CHAR, ("read",)),
    CharacteristicSpec(SERIAL_NUMBER_CHAR, ("read",)),
    CharacteristicSpec(FIRMWARE_REVISION_CHAR, ("read",)),
), optional=True)
BATTERY = ServiceSpec(BATTERY_SERVICE, (CharacteristicSpec(BATTERY_LEVEL_CHAR, ("read", "notify")),), optional=True)

WEARABLE_SERVICES: tuple[ServiceSpec, ...] = (IMU, DEVICE_INFORMATION, BATTERY)
