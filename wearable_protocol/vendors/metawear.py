"""MbientLab MetaWear protocol (MetaMotionR/S/C, MetaWear RG): BMI160 gyroscope and accelerometer streaming.

Sources (protocol facts only; the code is ours): MbientLab's MetaWear C++ SDK (github.com/mbientlab/
MetaWear-SDK-Cpp): the command and notification bytes in its unit tests ``test/test_gyro_bmi160.py`` and
``test/test_accelerometer_bmi160.py`` (which our tests replay, ``tests/link/test_vendor_metawear.py``),
and the GATT UUIDs of its ``src/metawear/platform/btle_connection.h`` / the SDK documentation; the LED module's
commands (module 0x02: play 0x01, stop 0x02, a pattern 0x03) and its 13-byte pattern (intensities, rise, high,
fall, pulse and delay times in ms, repeat count) from ``src/metawear/peripheral/led.h`` and ``led.cpp``, with the
"blink" preset's values.

Every message, both ways, is ``module | register | payload``. Commands go to the command characteristic,
data come back as notifications of the notify characteristic. The gyroscope (module 0x13) is configured
with ``13 03 <odr|bandwidth> <range>``, its data enabled with ``13 02 01 00``, subscribed with ``13 05 01``
(one sample per notification) or ``13 07 01`` (packed: three samples per notification), started with
``13 01 01``; the accelerometer (module 0x03) likewise with ``03 03``, ``03 02 01 00``, ``03 04 01`` or
``03 1C 01`` (packed) and ``03 01 01``. Samples are int16 x, y, z little-endian. Streamed data carry **no
time stamp and no counter**: sample times are arrival times and lost samples cannot be detected.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from ..codec import DecodeError
from ..gatt import CharacteristicSpec, ServiceSpec
from ..layout import BATTERY, DEVICE_INFORMATION

METAWEAR_SERVICE = "326a9000-85cb-9195-d9dd-464cfbbae75a"
COMMAND_CHAR = "326a9001-85cb-9195-d9dd-464cfbbae75a"  # write (without response)
NOTIFY_CHAR = "326a9006-85cb-9195-d9dd-464cfbbae75a"  # notify
SERVICES = (
    ServiceSpec(METAWEAR_SERVICE, (
        CharacteristicSpec(COMMAND_CHAR, ("write-without-response", "write")),
        CharacteristicSpec(NOTIFY_CHAR, ("notify",)),
    )),
    DEVICE_INFORMATION, BATTERY,
)


class Module(IntEnum):
    LED = 0x02
    ACCELEROMETER = 0x03
    GYROSCOPE = 0x13


class LedRegister(IntEnum):
    PLAY = 0x01  # 01: play the patterns written
    STOP = 0x02  # 01: stop and clear them
    PATTERN = 0x03  # color, 02, then the 13-byte pattern


class LedColor(IntEnum):
    GREEN = 0
    RED = 1
    BLUE = 2


BLINK_PULSE_MS = 500  # the SDK's "blink" preset: full intensity for 50 ms of every 500 ms
_LED_PATTERN = struct.Struct("<BBBBBBHHHHHB")


def led_blink(seconds: int, color: LedColor = LedColor.GREEN) -> tuple[bytes, bytes]:
    """The commands that blink the LED for ``seconds`` (1-127): the pattern, then play."""
    repeat = int(seconds) * 1000 // BLINK_PULSE_MS
    if not 1 <= repeat <= 254:  # 255 repeats forever
        raise ValueError(f"a MetaWear LED blinks 1 to 127 s; asked {seconds} s")
    pattern = _LED_PATTERN.pack(Module.LED, LedRegister.PATTERN, color, 2, 31, 0, 0, 50, 0, BLINK_PULSE_MS, 0, repeat)
    return pattern, bytes([Module.LED, LedRegister.PLAY, 1])


def parse_led_pattern(data: bytes) -> tuple[LedColor, int, int]:
    """A pattern command's color, pulse length (ms) and repeat count; DecodeError if it is not one."""
    if len(data) != _LED_PATTERN.size or data[0] != Module.LED or data[1] != LedRegister.PATTERN or data[2] > 2:
        raise DecodeError("length", f"not a MetaWear LED pattern: {data.hex()}")
    fields = _LED_PATTERN.unpack(data)
    return LedColor(fields[2]), fields[9], fields[11]


class Register(IntEnum):
    POWER = 0x01  # start (01) / stop (00) the sensor
    DATA_ENABLE = 0x02  # enable: 01 00, disable: 00 01
    CONFIG = 0x03  # odr|bandwidth, range
    ACC_DATA = 0x04  # accelerometer, one sample
    GYRO_DATA = 0x05  # gyroscope, one sample
    GYRO_PACKED = 0x07  # gyroscope, three samples
    ACC_PACKED = 0x1C  # accelerometer, three samples


BANDWIDTH_NORMAL = 0x20  # the config byte's upper bits: normal filter mode
# output data rate (Hz) -> BMI160 ODR code (the config byte's low nibble)
GYRO_ODR = {25.0: 6, 50.0: 7, 100.0: 8, 200.0: 9, 400.0: 10, 800.0: 11, 1600.0: 12, 3200.0: 13}
ACC_ODR = {12.5: 5, 25.0: 6, 50.0: 7, 100.0: 8, 200.0: 9, 400.0: 10, 800.0: 11, 1600.0: 12}
# full scale -> (range code, counts per unit): deg/s for the gyroscope, g for the accelerometer
GYRO_RANGES = {2000: (0, 16.4), 1000: (1, 32.8), 500: (2, 65.6), 250: (3, 131.2), 125: (4, 262.4)}
ACC_RANGES = {2: (0x03, 16384.0), 4: (0x05, 8192.0), 8: (0x08, 4096.0), 16: (0x0C, 2048.0)}


def _config(module: Module, odr_code: int, range_code: int) -> bytes:
    return bytes([module, Register.CONFIG, BANDWIDTH_NORMAL | odr_code, range_code])


def gyro_config(rate_hz: float, full_scale_dps: int) -> bytes:
    """``13 03 <odr> <range>``; KeyError for a rate or range the BMI160 does not have."""
    return _config(Module.GYROSCOPE, GYRO_ODR[float(rate_hz)], GYRO_RANGES[int(full_scale_dps)][0])


def accel_config(rate_hz: float, range_g: int) -> bytes:
    """``03 03 <odr> <range>``."""
    return _config(Module.ACCELEROMETER, ACC_ODR[float(rate_hz)], ACC_RANGES[int(range_g)][0])


def parse_config(data: bytes) -> tuple[Module, float, int]:
    """(module, rate Hz, full scale) from a config command."""
    if len(data) != 4 or data[1] != Register.CONFIG or data[0] not in (Module.GYROSCOPE, Module.ACCELEROMETER):
        raise DecodeError("not_config", f"a MetaWear config command is 4 bytes: module, 03, odr, range; got {bytes(data).hex(' ')}")
    module = Module(data[0])
    odr, ranges = (GYRO_ODR, GYRO_RANGES) if module == Module.GYROSCOPE else (ACC_ODR, ACC_RANGES)
    rate = next((r for r, c in odr.items() if c == data[2] & 0x0F), None)
    full = next((f for f, (c, _) in ranges.items() if c == data[3]), None)
    if rate is None or full is None:
        raise DecodeError("invalid_config", f"unknown odr code {data[2]:#04x} or range code {data[3]:#04x}")
    return module, rate, full


def power(module: Module, on: bool) -> bytes:
    return bytes([module, Register.POWER, int(on)])


def data_enable(module: Module, on: bool) -> bytes:
    return bytes([module, Register.DATA_ENABLE, 1, 0] if on else [module, Register.DATA_ENABLE, 0, 1])


def subscribe(module: Module, register: Register, on: bool = True) -> bytes:
    return bytes([module, register, int(on)])


@dataclass(frozen=True, eq=False)
class Notification:
    """A data notification: ``counts`` (n, 3) int16 samples of ``module`` (n = 1, or 3 when packed)."""

    module: Module
    register: int
    counts: np.ndarray


_DATA_REGISTERS: dict[tuple[int, int], int] = {(Module.GYROSCOPE, Register.GYRO_DATA): 1, (Module.GYROSCOPE, Register.GYRO_PACKED): 3,
                   (Module.ACCELEROMETER, Register.ACC_DATA): 1, (Module.ACCELEROMETER, Register.ACC_PACKED): 3}


def decode_notification(data: bytes) -> Notification:
    """A gyroscope or accelerometer data notification (single or packed)."""
    if len(data) < 2:
        raise DecodeError("too_short", f"a MetaWear notification has a module and a register byte; got {len(data)} bytes")
    key = (data[0], data[1])
    n = _DATA_REGISTERS.get(key)
    if n is None:
        raise DecodeError("not_data", f"module {data[0]:#04x} register {data[1]:#04x} is not gyroscope or accelerometer data")
    if len(data) != 2 + 6 * n:
        raise DecodeError("length", f"{n} sample(s) need {2 + 6 * n} bytes; got {len(data)}")
    counts = np.frombuffer(bytes(data[2:]), "<i2").reshape(n, 3).astype(np.int64)
    return Notification(Module(data[0]), data[1], counts)


def encode_notification(module: Module, counts: np.ndarray) -> bytes:
    """One sample (1, 3) or a packed three (3, 3) as the device sends them."""
    c = np.asarray(counts, dtype=np.int64)
    if c.shape not in ((1, 3), (3, 3)):
        raise ValueError("counts must be (1, 3) or (3, 3)")
    packed = c.shape[0] == 3
    register = (Register.GYRO_PACKED if packed else Register.GYRO_DATA) if module == Module.GYROSCOPE else (
        Register.ACC_PACKED if packed else Register.ACC_DATA)
    return bytes([module, register]) + np.clip(c, -32768, 32767).astype("<i2").tobytes()


def gyro_dps(counts: np.ndarray, full_scale_dps: int) -> np.ndarray:
    """Counts to deg/s at the configured range."""
    return np.asarray(counts, dtype=np.float64) / GYRO_RANGES[int(full_scale_dps)][1]


def accel_g(counts: np.ndarray, range_g: int) -> np.ndarray:
    """Counts to g at the configured range."""
    return np.asarray(counts, dtype=np.float64) / ACC_RANGES[int(range_g)][1]
