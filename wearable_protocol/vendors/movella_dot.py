"""Movella DOT (formerly Xsens DOT): the Configuration and Measurement services, streaming "Rate quantities".

Source (protocol facts only; the code is ours): Movella's *Movella DOT BLE Service Specification*, document
XD0506P, revision C, July 2023. Every attribute is ``1517xxxx-4947-11E9-8646-D663BD873D93`` (section 1.1); all
members little-endian (1.3); the advertisement's local name is "Movella DOT" (firmware 2.x; "Xsens DOT" before),
company identifier 2182 (1.2, 1.4). Configuration service 0x1000: Device info 0x1001 (34 bytes, read: MAC, firmware
version and build date, SoftDevice, serial number, short product code "XS-T01"/"XS-T02", Table 6), Device control
0x1002 (32 bytes, read and write: a visit-index bitmask saying which fields a write sets, identify, power, power
saving, tag, **output rate** (u16 Hz: 1, 4, 10, 12, 15, 20, 30 or 60 for real-time streaming; 120 only when
recording) and filter profile, Table 7), Device report 0x1004. Measurement service 0x2000: Control 0x2001 (3
bytes: type 1 = measurement, action 0 stop / 1 start, payload mode, Table 13), Long 0x2002, Medium 0x2003 (up to
40 bytes, trailing bytes zero) and Short 0x2004 payload characteristics (notify). Battery service 0x3000: 0x3001
(level %, charging).

**The payload mode.** Of the modes that carry angular velocity (Table 13-15): *Rate quantities* (21; timestamp,
acceleration, angular velocity: 28 bytes, medium characteristic), *Rate quantities (with mag)* (20; the same and
the magnetic field, 34 bytes), *Custom mode 1* (22; timestamp, Euler angles, free acceleration, angular velocity),
*Custom mode 3* (24; timestamp, quaternion, angular velocity), *Custom mode 5* (26; timestamp, quaternion,
acceleration, angular velocity, 44 bytes, long characteristic). All stream at the same rates (60 Hz the highest
for real-time streaming), so gyrocal takes the one that carries exactly what a calibration reads: Rate quantities,
the **calibrated acceleration** in m/s^2 and the **rate of turn** in deg/s in sensor coordinates, float32 each
(Table 17). Custom mode 1's free acceleration has gravity taken out in earth coordinates (no tilt in it); the
quaternion modes add orientation gyrocal does not use; dq/dv (Delta quantities) carry no rate. The timestamp is
the sensor's clock in microseconds (u32, wrapping every 71.6 minutes); there is **no sample counter**: lost samples
are found from gaps in the time stamps, one output period (16 667 us at 60 Hz) apart.

**Identify.** A Device control write with visit-index bit 0 and Identifying = 0x01: the LED fast-blinks eight times
and pauses, in red, for 10 seconds (Table 7).

**What the DOT does before it sends.** The readings are the DOT's *calibrated* ones: its accelerometer and gyroscope
are factory calibrated and sampled at 800 Hz, integrated (strapdown integration, coning and sculling compensated)
to orientation and velocity increments at the output rate, and the rates sent are those increments turned back into
rates (inverse strapdown integration; the *Xsens DOT User Manual*, XD0502P, sections 3.1 and 4.2). A gyrocal
calibration on top of it is therefore a **correction of the factory calibration as this DOT is now** (its K and b
measured after the factory's: K near identity, b the bias of this power-up), and a rate is an average over the
output period, not a filtered sample: the 800 Hz integration leaves no aliasing of fast hand motion at 60 Hz.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from ..codec import DecodeError
from ..gatt import CharacteristicSpec, ServiceSpec


def _uuid(short: int) -> str:
    return f"1517{short:04x}-4947-11e9-8646-d663bd873d93"


CONFIGURATION_SERVICE = _uuid(0x1000)
DEVICE_INFO_CHAR = _uuid(0x1001)  # read, 34 bytes
DEVICE_CONTROL_CHAR = _uuid(0x1002)  # read, write, 32 bytes
DEVICE_REPORT_CHAR = _uuid(0x1004)  # notify, 36 bytes
MEASUREMENT_SERVICE = _uuid(0x2000)
CONTROL_CHAR = _uuid(0x2001)  # read, write, 3 bytes
LONG_PAYLOAD_CHAR = _uuid(0x2002)  # notify, 63 bytes
MEDIUM_PAYLOAD_CHAR = _uuid(0x2003)  # notify, 40 bytes
SHORT_PAYLOAD_CHAR = _uuid(0x2004)  # notify, 20 bytes
BATTERY_SERVICE = _uuid(0x3000)
BATTERY_CHAR = _uuid(0x3001)  # read, notify: level %, charging

NAME = "Movella DOT"  # the advertised local name (firmware 2.x); "Xsens DOT" on earlier firmware
OLD_NAME = "Xsens DOT"
COMPANY_ID = 2182  # Movella Technologies B.V.'s Bluetooth company identifier
STREAMING_RATES_HZ = (1, 4, 10, 12, 15, 20, 30, 60)  # real-time streaming (120 Hz is for recording only)
GYRO_FULL_SCALE_DPS = 2000  # the DOT's gyroscope range (user manual's specifications; not settable over BLE)
ACCEL_RANGE_G = 16
IDENTIFY_S = 10  # the LED's identify pattern lasts this long (Table 7)
STANDARD_GRAVITY = 9.80665  # m/s^2 per g: the DOT sends m/s^2

SERVICES = (
    ServiceSpec(CONFIGURATION_SERVICE, (
        CharacteristicSpec(DEVICE_INFO_CHAR, ("read",)),
        CharacteristicSpec(DEVICE_CONTROL_CHAR, ("read", "write")),
        CharacteristicSpec(DEVICE_REPORT_CHAR, ("notify",)),
    )),
    ServiceSpec(MEASUREMENT_SERVICE, (
        CharacteristicSpec(CONTROL_CHAR, ("read", "write")),
        CharacteristicSpec(LONG_PAYLOAD_CHAR, ("notify",)),
        CharacteristicSpec(MEDIUM_PAYLOAD_CHAR, ("notify",)),
        CharacteristicSpec(SHORT_PAYLOAD_CHAR, ("notify",)),
    )),
    ServiceSpec(BATTERY_SERVICE, (CharacteristicSpec(BATTERY_CHAR, ("read", "notify")),)),
)


class PayloadMode(IntEnum):
    """The Control characteristic's payload modes that carry angular velocity (Table 13)."""

    RATE_QUANTITIES_WITH_MAG = 20
    RATE_QUANTITIES = 21
    CUSTOM_MODE_1 = 22
    CUSTOM_MODE_3 = 24
    CUSTOM_MODE_5 = 26


MEASUREMENT_TYPE = 1
_CONTROL = struct.Struct("<BBB")
_RATE = struct.Struct("<I3f3f")  # timestamp us, acceleration m/s^2, angular velocity deg/s (28 bytes)
MEDIUM_LENGTH = 40  # the medium payload characteristic's value: the mode's bytes, then zeros


@dataclass(frozen=True)
class Control:
    """The Measurement service's Control characteristic: start or stop, and the payload mode."""

    action: int  # 0 stop, 1 start
    payload_mode: int
    type: int = MEASUREMENT_TYPE

    def encode(self) -> bytes:
        return _CONTROL.pack(self.type, self.action, self.payload_mode)

    @classmethod
    def decode(cls, data: bytes) -> Control:
        if len(data) != _CONTROL.size:
            raise DecodeError("length", f"the DOT's measurement control is {_CONTROL.size} bytes; got {len(data)}")
        kind, action, mode = _CONTROL.unpack(data)
        if kind != MEASUREMENT_TYPE or action not in (0, 1):
            raise DecodeError("invalid_value", f"measurement control type {kind} (1) or action {action} (0 or 1) is not valid")
        return cls(action, mode, kind)


# Device control (Table 7): visit index, identify, power, power-saving X min/s, Y min/s, tag length, tag (16),
# output rate (u16), filter profile, reserved (5)
_DEVICE_CONTROL = struct.Struct("<BBBBBBBB16sHB5s")
VISIT_IDENTIFY, VISIT_POWER, VISIT_POWER_SAVING, VISIT_TAG, VISIT_OUTPUT_RATE, VISIT_FILTER = (1 << i for i in range(6))


@dataclass(frozen=True)
class DeviceControl:
    """The Device control characteristic (32 bytes). A write sets only the fields its ``visit`` bits name."""

    visit: int = 0
    identify: int = 0
    power: int = 0
    saving_adv_min: int = 10
    saving_adv_s: int = 0
    saving_conn_min: int = 30
    saving_conn_s: int = 0
    tag: str = NAME
    output_rate_hz: int = 60
    filter_profile: int = 0
    reserved: bytes = field(default=bytes(5))

    def encode(self) -> bytes:
        tag = self.tag.encode("utf-8")[:16]
        return _DEVICE_CONTROL.pack(self.visit, self.identify, self.power, self.saving_adv_min, self.saving_adv_s,
                                    self.saving_conn_min, self.saving_conn_s, len(tag), tag.ljust(16, b"\0"),
                                    self.output_rate_hz, self.filter_profile, self.reserved)

    @classmethod
    def decode(cls, data: bytes) -> DeviceControl:
        if len(data) != _DEVICE_CONTROL.size:
            raise DecodeError("length", f"the DOT's device control is {_DEVICE_CONTROL.size} bytes; got {len(data)}")
        visit, ident, power, am, as_, cm, cs, tag_len, tag, rate, profile, reserved = _DEVICE_CONTROL.unpack(data)
        if tag_len > 16:
            raise DecodeError("invalid_value", f"device tag length {tag_len} (0-16)")
        return cls(visit, ident, power, am, as_, cm, cs, tag[:tag_len].decode("utf-8", "replace"), rate, profile, reserved)

    @classmethod
    def set_output_rate(cls, rate_hz: int) -> DeviceControl:
        """The write that sets the output rate alone."""
        return cls(visit=VISIT_OUTPUT_RATE, output_rate_hz=rate_hz)

    @classmethod
    def identify_now(cls) -> DeviceControl:
        """The write that makes the LED blink (Identifying = 0x01)."""
        return cls(visit=VISIT_IDENTIFY, identify=1)


# Device info (Table 6): MAC (6), version major, minor, revision, build year (u16), month, day, hour, minute, second,
# SoftDevice (u32), serial number (u64), short product code (6)
_DEVICE_INFO = struct.Struct("<6sBBBHBBBBBIQ6s")


@dataclass(frozen=True)
class DeviceInfo:
    """The Device info characteristic (34 bytes)."""

    mac: bytes
    version: tuple[int, int, int]
    build: tuple[int, int, int, int, int, int]
    softdevice: int
    serial: int
    product_code: str

    def encode(self) -> bytes:
        return _DEVICE_INFO.pack(self.mac, *self.version, *self.build, self.softdevice, self.serial,
                                 self.product_code.encode("ascii")[:6].ljust(6, b"\0"))

    @classmethod
    def decode(cls, data: bytes) -> DeviceInfo:
        if len(data) != _DEVICE_INFO.size:
            raise DecodeError("length", f"the DOT's device info is {_DEVICE_INFO.size} bytes; got {len(data)}")
        v = _DEVICE_INFO.unpack(data)
        return cls(v[0], (v[1], v[2], v[3]), tuple(v[4:10]), v[10], v[11], v[12].rstrip(b"\0").decode("ascii", "replace"))

    @property
    def firmware(self) -> str:
        return ".".join(str(x) for x in self.version)


@dataclass(frozen=True)
class RateSample:
    """One Rate quantities notification: the sensor's time stamp (us), acceleration (g) and rate of turn (deg/s)."""

    timestamp_us: int
    accel_g: np.ndarray  # (3,)
    gyro_dps: np.ndarray  # (3,)


def decode_rate_quantities(data: bytes) -> RateSample:
    """A Rate quantities notification of the medium payload characteristic (28 bytes, then zeros up to 40)."""
    if not _RATE.size <= len(data) <= MEDIUM_LENGTH:
        raise DecodeError("length", f"a DOT Rate quantities notification is {_RATE.size} to {MEDIUM_LENGTH} bytes; got {len(data)}")
    if any(data[_RATE.size:]):
        raise DecodeError("invalid_value", "a DOT Rate quantities notification has bytes after its 28 that are not zero")
    v = _RATE.unpack_from(data)
    values = np.array(v[1:], dtype=np.float64)
    if not np.all(np.isfinite(values)):
        raise DecodeError("invalid_value", "a DOT Rate quantities notification holds a value that is not a number")
    return RateSample(int(v[0]), values[0:3] / STANDARD_GRAVITY, values[3:6])


def encode_rate_quantities(timestamp_us: int, accel_g: np.ndarray, gyro_dps: np.ndarray) -> bytes:
    """The notification the DOT sends for these values (float32, m/s^2 and deg/s), padded to 40 bytes."""
    a = np.asarray(accel_g, float) * STANDARD_GRAVITY
    g = np.asarray(gyro_dps, float)
    return _RATE.pack(int(timestamp_us) & 0xFFFFFFFF, *a, *g).ljust(MEDIUM_LENGTH, b"\0")
