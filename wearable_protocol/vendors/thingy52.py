"""Nordic Thingy:52 Motion service: raw accelerometer, gyroscope and compass at the motion processing rate.

Sources (protocol facts only; the code is ours): Nordic's Thingy:52 firmware (github.com/NordicSemiconductor/
Nordic-Thingy52-FW): ``include/ble_services/ble_tms.h`` (the packed ``ble_tms_raw_t`` and ``ble_tms_config_t``
structs, the configuration limits) and ``include/drivers/drv_motion.h`` (the raw data's fixed-point formats:
accelerometer Q6.10 in g, gyroscope Q11.5 in deg/s, compass Q12.4 in uT); the Thingy's 128-bit UUID base
``EF68xxxx-9B35-4933-9B10-52FFA9740042`` with the Motion service at 0x0400, its configuration at 0x0401 and
the raw data at 0x0406. Nordic publishes no example bytes for these, so our tests build them from the
structs' layout. The LED: ``include/ble_services/ble_uis.h`` (User Interface service 0x0300, LED characteristic
0x0301: a mode byte, then for "breathe" (2) a colour mix 1-7 (bits R, G, B), an intensity 1-100 % and a u16 delay
between breaths, 1-10000 ms).

The central writes the configuration (motion processing frequency 1-200 Hz) and enables notifications of
the raw data characteristic: one sample per notification, **no time stamp and no counter** (sample times
are arrival times; lost samples cannot be detected). The gyroscope's range is fixed by the firmware
(±2000 deg/s on the MPU-9250) and its resolution by the Q11.5 format: 1/32 deg/s.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from ..codec import DecodeError
from ..gatt import CharacteristicSpec, ServiceSpec
from ..layout import BATTERY


def _uuid(short: int) -> str:
    return f"ef68{short:04x}-9b35-4933-9b10-52ffa9740042"


CONFIGURATION_SERVICE = _uuid(0x0100)  # the advertised one (m_ble.c advertises the Thingy Configuration service)
DEVICE_NAME_CHAR = _uuid(0x0101)
MOTION_SERVICE = _uuid(0x0400)
CONFIG_CHAR = _uuid(0x0401)  # read, write: ble_tms_config_t
RAW_DATA_CHAR = _uuid(0x0406)  # notify: ble_tms_raw_t
UI_SERVICE = _uuid(0x0300)
LED_CHAR = _uuid(0x0301)  # read, write: ble_uis_led_t
LED_MODE_BREATHE = 2
LED_GREEN = 2  # colour mix: bit 0 red, bit 1 green, bit 2 blue
SERVICES = (
    ServiceSpec(CONFIGURATION_SERVICE, (CharacteristicSpec(DEVICE_NAME_CHAR, ("read", "write")),)),
    ServiceSpec(MOTION_SERVICE, (
        CharacteristicSpec(CONFIG_CHAR, ("read", "write")),
        CharacteristicSpec(RAW_DATA_CHAR, ("notify",)),
    )),
    ServiceSpec(UI_SERVICE, (CharacteristicSpec(LED_CHAR, ("read", "write")),)),
    BATTERY,
)
_LED_LENGTHS = {0: 1, 1: 4, 2: 5, 3: 3}  # mode -> length of the LED characteristic's value


def led_breathe(color_mix: int = LED_GREEN, intensity_pct: int = 100, delay_ms: int = 100) -> bytes:
    """The LED characteristic's value that makes it breathe (fade in, on, fade out) every ``delay_ms``."""
    return struct.pack("<BBBH", LED_MODE_BREATHE, color_mix, intensity_pct, delay_ms)


def check_led(data: bytes) -> bytes:
    """An LED characteristic value as the firmware takes it (mode and length); DecodeError otherwise."""
    if not data or _LED_LENGTHS.get(data[0]) != len(data):
        raise DecodeError("length", f"not a Thingy:52 LED value: {bytes(data).hex()}")
    return bytes(data)

ACCEL_FRACTION_BITS = 10  # Q6.10, g
GYRO_FRACTION_BITS = 5  # Q11.5, deg/s
COMPASS_FRACTION_BITS = 4  # Q12.4, uT
GYRO_FULL_SCALE_DPS = 2000
MOTION_FREQ_MIN_HZ, MOTION_FREQ_MAX_HZ = 1, 200
_CONFIG = struct.Struct("<HHHHB")  # step counter, temperature compensation, compass compensation intervals (ms), Hz, WoM
_RAW = struct.Struct("<9h")


@dataclass(frozen=True)
class MotionConfig:
    """The Motion service's configuration characteristic."""

    pedometer_interval_ms: int = 100
    temperature_interval_ms: int = 100
    compass_interval_ms: int = 100
    motion_freq_hz: int = 100
    wake_on_motion: int = 1

    def encode(self) -> bytes:
        return _CONFIG.pack(self.pedometer_interval_ms, self.temperature_interval_ms, self.compass_interval_ms,
                            self.motion_freq_hz, self.wake_on_motion)

    @classmethod
    def decode(cls, data: bytes) -> MotionConfig:
        if len(data) != _CONFIG.size:
            raise DecodeError("length", f"the Thingy:52 motion configuration is {_CONFIG.size} bytes; got {len(data)}")
        cfg = cls(*_CONFIG.unpack(data))
        if not MOTION_FREQ_MIN_HZ <= cfg.motion_freq_hz <= MOTION_FREQ_MAX_HZ or cfg.wake_on_motion > 1:
            raise DecodeError("invalid_value", f"motion frequency {cfg.motion_freq_hz} Hz (1-200) or wake-on-motion "
                                               f"{cfg.wake_on_motion} (0 or 1) out of range")
        return cfg


@dataclass(frozen=True)
class RawSample:
    """One raw data notification in physical units."""

    accel_g: np.ndarray  # (3,)
    gyro_dps: np.ndarray  # (3,)
    compass_ut: np.ndarray  # (3,)


def decode_raw(data: bytes) -> RawSample:
    """A raw data notification: int16 accelerometer, gyroscope and compass, each x, y, z, fixed point."""
    if len(data) != _RAW.size:
        raise DecodeError("length", f"a Thingy:52 raw data notification is {_RAW.size} bytes; got {len(data)}")
    v = np.array(_RAW.unpack(data), dtype=np.float64)
    return RawSample(v[0:3] / (1 << ACCEL_FRACTION_BITS), v[3:6] / (1 << GYRO_FRACTION_BITS),
                     v[6:9] / (1 << COMPASS_FRACTION_BITS))


def encode_raw(accel_g: np.ndarray, gyro_dps: np.ndarray, compass_ut: np.ndarray | None = None) -> bytes:
    """The notification the firmware sends for these values (rounded to its fixed point, clipped to int16)."""
    parts = [np.asarray(accel_g, float) * (1 << ACCEL_FRACTION_BITS), np.asarray(gyro_dps, float) * (1 << GYRO_FRACTION_BITS),
             np.zeros(3) if compass_ut is None else np.asarray(compass_ut, float) * (1 << COMPASS_FRACTION_BITS)]
    counts = np.clip(np.round(np.concatenate(parts)), -32768, 32767).astype(int)
    return _RAW.pack(*counts)
