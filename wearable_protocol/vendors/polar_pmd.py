"""Polar Measurement Data (PMD) service: Polar Verity Sense, OH1, H10 and the other Polar sensors.

Sources (protocol facts only; the code is ours): Polar's BLE SDK (github.com/polarofficial/polar-ble-sdk),
``BlePMDClient.kt`` (UUIDs, control-point exchange, delta-frame layout), ``PmdSetting.kt`` (settings TLV),
``PmdControlPointResponse.kt`` (reply layout and status codes), ``PmdMeasurementType.kt`` (types and the
feature bit field), ``PmdTimeStampUtils.kt`` (sample times) and ``GyrData.kt`` (gyroscope frames); its
unit tests' byte sequences check our decoders (``tests/link/test_vendor_polar.py``).

The exchange: read the control point (feature bit field), enable its indications and the data
notifications, write GET_MEASUREMENT_SETTINGS for the gyroscope, then REQUEST_MEASUREMENT_START with the
chosen settings; the start reply carries the FACTOR that scales the frames' integers to deg/s. Each data
notification is one frame: measurement type, the 64-bit time stamp (ns since 2000-01-01) of its **last**
sample, the frame type (bit 7: delta-compressed), then the samples. No sample counter: lost frames show
only as a gap in the time stamps.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from ..codec import DecodeError
from ..gatt import CharacteristicSpec, ServiceSpec
from ..layout import BATTERY, DEVICE_INFORMATION

PMD_SERVICE = "fb005c80-02e7-f387-1cad-8acd2d8df0c8"
PMD_CONTROL_CHAR = "fb005c81-02e7-f387-1cad-8acd2d8df0c8"  # read (features), write, indicate (replies)
PMD_DATA_CHAR = "fb005c82-02e7-f387-1cad-8acd2d8df0c8"  # notify: data frames

SERVICES = (
    ServiceSpec(PMD_SERVICE, (
        CharacteristicSpec(PMD_CONTROL_CHAR, ("read", "write", "indicate")),
        CharacteristicSpec(PMD_DATA_CHAR, ("notify",)),
    )),
    DEVICE_INFORMATION, BATTERY,
)

RESPONSE_CODE = 0xF0  # first byte of every control-point reply
FEATURES_CODE = 0x0F  # first byte of the control point's read value
MEASUREMENT_STOPPED = 0x01  # unsolicited: the device stopped the listed measurements
HEADER_SIZE = 10  # type, u64 time stamp, frame type


class MeasurementType(IntEnum):
    ECG = 0
    PPG = 1
    ACC = 2
    PPI = 3
    GYRO = 5
    MAGNETOMETER = 6


class Command(IntEnum):
    GET_MEASUREMENT_SETTINGS = 1
    REQUEST_MEASUREMENT_START = 2
    STOP_MEASUREMENT = 3


class Status(IntEnum):
    SUCCESS = 0
    INVALID_OP_CODE = 1
    INVALID_MEASUREMENT_TYPE = 2
    NOT_SUPPORTED = 3
    INVALID_LENGTH = 4
    INVALID_PARAMETER = 5
    ALREADY_IN_STATE = 6
    INVALID_RESOLUTION = 7
    INVALID_SAMPLE_RATE = 8
    INVALID_RANGE = 9
    INVALID_MTU = 10
    INVALID_NUMBER_OF_CHANNELS = 11
    INVALID_STATE = 12
    DEVICE_IN_CHARGER = 13
    DISK_FULL = 14


class SettingType(IntEnum):
    SAMPLE_RATE = 0  # Hz
    RESOLUTION = 1  # bits
    RANGE = 2  # deg/s for the gyroscope, g for the accelerometer
    RANGE_MILLIUNIT = 3
    CHANNELS = 4
    FACTOR = 5  # IEEE-754 float bits: physical unit per count


FIELD_SIZE = {SettingType.SAMPLE_RATE: 2, SettingType.RESOLUTION: 2, SettingType.RANGE: 2,
              SettingType.RANGE_MILLIUNIT: 4, SettingType.CHANNELS: 1, SettingType.FACTOR: 4}

# feature bit field: (byte index, bit) of each measurement type in the control point's read value
_FEATURE_BITS = {MeasurementType.ECG: (1, 0x01), MeasurementType.PPG: (1, 0x02), MeasurementType.ACC: (1, 0x04),
                 MeasurementType.PPI: (1, 0x08), MeasurementType.GYRO: (1, 0x20), MeasurementType.MAGNETOMETER: (1, 0x40)}

Settings = dict[SettingType, tuple[int, ...]]


def parse_settings(data: bytes) -> Settings:
    """A settings TLV (type u8, count u8, count values of the type's size, little-endian signed) as a dict."""
    out: Settings = {}
    i = 0
    while i < len(data):
        if i + 2 > len(data):
            raise DecodeError("truncated", f"settings end inside the header at byte {i}")
        try:
            kind = SettingType(data[i])
        except ValueError:
            raise DecodeError("unknown_setting", f"setting type {data[i]} at byte {i}") from None
        count, size = data[i + 1], FIELD_SIZE[kind]
        i += 2
        if i + count * size > len(data):
            raise DecodeError("truncated", f"{kind.name} announces {count} values of {size} bytes, {len(data) - i} left")
        out[kind] = tuple(int.from_bytes(data[i + k * size: i + (k + 1) * size], "little", signed=True) for k in range(count))
        i += count * size
    return out


def encode_settings(values: dict[SettingType, int | tuple[int, ...]]) -> bytes:
    """The TLV form of ``values`` (one value, or a tuple of the values a device offers, per setting)."""
    out = bytearray()
    for kind, v in values.items():
        items = v if isinstance(v, tuple) else (v,)
        out += bytes([int(kind), len(items)])
        for item in items:
            out += int(item).to_bytes(FIELD_SIZE[kind], "little", signed=item < 0)
    return bytes(out)


def factor_bits(factor: float) -> int:
    """The FACTOR setting's integer (the float's IEEE-754 bits, as signed 32-bit)."""
    return int(struct.unpack("<i", struct.pack("<f", factor))[0])


def factor_value(bits: int) -> float:
    """The float a FACTOR setting's integer stands for."""
    return float(struct.unpack("<f", struct.pack("<i", bits))[0])


def encode_command(command: Command, measurement: MeasurementType, settings: bytes = b"") -> bytes:
    """A control-point write: opcode, measurement type, settings TLV."""
    return bytes([int(command), int(measurement)]) + settings


@dataclass(frozen=True)
class ControlResponse:
    """A control-point reply: F0, opcode, measurement type, status, more, parameters."""

    opcode: int
    measurement: int
    status: int
    more: bool = False
    parameters: bytes = b""

    @classmethod
    def decode(cls, data: bytes) -> ControlResponse:
        if len(data) < 4 or data[0] != RESPONSE_CODE:
            raise DecodeError("not_a_reply", f"a PMD reply starts with F0 and has at least 4 bytes; got {bytes(data).hex(' ')}")
        ok = data[3] == Status.SUCCESS
        return cls(data[1], data[2], data[3], ok and len(data) > 4 and data[4] != 0, bytes(data[5:]) if ok else b"")

    def encode(self) -> bytes:
        return bytes([RESPONSE_CODE, self.opcode, self.measurement, self.status, int(self.more)]) + self.parameters

    @property
    def status_name(self) -> str:
        try:
            return Status(self.status).name.lower()
        except ValueError:
            return f"status {self.status}"


def parse_features(data: bytes) -> set[MeasurementType]:
    """The measurement types the device offers, from the control point's read value."""
    if len(data) < 3 or data[0] != FEATURES_CODE:
        raise DecodeError("not_features", f"the PMD feature value starts with 0F and has 3 bytes or more; got {bytes(data).hex(' ')}")
    return {t for t, (i, bit) in _FEATURE_BITS.items() if data[i] & bit}


def encode_features(types: set[MeasurementType]) -> bytes:
    out = bytearray([FEATURES_CODE, 0, 0])
    for t in types:
        i, bit = _FEATURE_BITS[t]
        out[i] |= bit
    return bytes(out)


# --------------------------------------------------------------------------- data frames


@dataclass(frozen=True, eq=False)
class Frame:
    """One data notification. ``values`` (n, channels): the samples' integers (float32 values for frame
    type 1), before the factor; ``timestamp_ns``: the last sample's time."""

    measurement: int
    timestamp_ns: int
    frame_type: int
    compressed: bool
    values: np.ndarray

    def scaled(self, factor: float) -> np.ndarray:
        """The samples in physical units (deg/s for the gyroscope)."""
        return self.values.astype(np.float64) * factor


# (measurement, frame type) -> bytes per channel and whether the values are float32 bits (GyrData.kt, AccData.kt,
# MagData.kt): the gyroscope sends int16 (type 0) or float32 (type 1); the accelerometer int8, int16 or int24
_LAYOUTS: dict[tuple[int, int], tuple[int, bool]] = {
    (MeasurementType.GYRO, 0): (2, False), (MeasurementType.GYRO, 1): (4, True),
    (MeasurementType.ACC, 0): (1, False), (MeasurementType.ACC, 1): (2, False), (MeasurementType.ACC, 2): (3, False),
    (MeasurementType.MAGNETOMETER, 0): (2, False),
}
CHANNELS = 3


def _signed(raw: bytes, size: int) -> np.ndarray:
    """Little-endian signed integers of ``size`` bytes each."""
    b = np.frombuffer(raw, np.uint8).reshape(-1, size).astype(np.int64)
    v = b @ (np.int64(1) << (8 * np.arange(size, dtype=np.int64)))
    return np.where(v >= (1 << (8 * size - 1)), v - (1 << (8 * size)), v)


def decode_frame(data: bytes, channels: int = CHANNELS) -> Frame:
    """A 3-axis data frame of the gyroscope, accelerometer or magnetometer: raw, or delta-compressed (a
    reference sample, then blocks of deltas; for float frames the deltas act on the float's bits)."""
    if len(data) < HEADER_SIZE + 1:
        raise DecodeError("too_short", f"a PMD frame has a {HEADER_SIZE}-byte header and samples; got {len(data)} bytes")
    measurement = data[0] & 0x3F
    (ts,) = struct.unpack_from("<Q", data, 1)
    compressed, frame_type = bool(data[9] & 0x80), data[9] & 0x7F
    layout = _LAYOUTS.get((measurement, frame_type))
    if layout is None:
        raise DecodeError("frame_type", f"measurement {measurement} frame type {frame_type} is not a 3-axis frame")
    size, is_float = layout
    body = bytes(data[HEADER_SIZE:])
    if not compressed:
        if is_float or len(body) % (size * channels):
            raise DecodeError("length", f"a raw frame of {len(body)} bytes is not whole {size}-byte samples")
        return Frame(measurement, ts, frame_type, False, _signed(body, size).reshape(-1, channels))
    return Frame(measurement, ts, frame_type, True, _delta_decode(body, channels, size, is_float))


def _delta_decode(body: bytes, channels: int, size: int, is_float: bool) -> np.ndarray:
    ref_len = channels * size
    if len(body) < ref_len:
        raise DecodeError("too_short", f"the reference sample needs {ref_len} bytes; the frame has {len(body)}")
    ref = _signed(body[:ref_len], size)
    rows = [ref[None, :]]
    i = ref_len
    while i < len(body):
        if i + 2 > len(body):
            raise DecodeError("truncated", "a delta block's header is cut short")
        width, count = body[i], body[i + 1]
        i += 2
        bits = width * count * channels
        n_bytes = (bits + 7) // 8
        if width == 0 or width > 32 or i + n_bytes > len(body):
            raise DecodeError("delta_block", f"delta block of {count} samples x {width} bits at byte {i} does not fit")
        raw = np.unpackbits(np.frombuffer(body[i:i + n_bytes], np.uint8), bitorder="little")[:bits]
        fields = raw.reshape(count * channels, width).astype(np.int64) @ (np.int64(1) << np.arange(width, dtype=np.int64))
        fields = np.where(fields >= (1 << (width - 1)), fields - (1 << width), fields)  # sign extension
        rows.append(fields.reshape(count, channels))
        i += n_bytes
    values = np.cumsum(np.concatenate(rows), axis=0)
    if is_float:  # deltas on the float's bits, wrapping as 32-bit integers
        return (values & 0xFFFFFFFF).astype(np.uint32).view(np.float32).astype(np.float64)
    return values


INT16_FRAME_TYPE = {MeasurementType.GYRO: 0, MeasurementType.ACC: 1, MeasurementType.MAGNETOMETER: 0}


def encode_frame(measurement: MeasurementType, timestamp_ns: int, values: np.ndarray, compressed: bool = True) -> bytes:
    """A frame of int16 samples ``values`` (n, 3) in the measurement's int16 frame type: delta-compressed (one
    delta block, the narrowest width that holds every delta) or raw."""
    v = np.asarray(values, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != CHANNELS or len(v) == 0 or len(v) > 256:
        raise ValueError("values must be (n, 3) with 1 <= n <= 256")
    frame_type = INT16_FRAME_TYPE[MeasurementType(measurement)]
    header = struct.pack("<BQB", int(measurement), int(timestamp_ns), frame_type | (0x80 if compressed else 0x00))
    if not compressed:
        return header + v.astype("<i2").tobytes()
    body = v[0].astype("<i2").tobytes()
    if len(v) > 1:
        d = np.diff(v, axis=0)
        width = max(2, int(np.max(np.where(d < 0, -d - 1, d))).bit_length() + 1)
        fields = (d.reshape(-1) & ((1 << width) - 1)).astype(np.int64)
        bits = ((fields[:, None] >> np.arange(width)) & 1).astype(np.uint8).reshape(-1)
        body += bytes([width, len(d)]) + np.packbits(bits, bitorder="little").tobytes()
    return header + body


def sample_times_ns(previous_ns: int, frame_ns: int, n: int, rate_hz: float) -> np.ndarray:
    """Polar's rule for the samples' times: spread evenly after the previous frame's last sample and up to
    this frame's time stamp; for a first frame (``previous_ns`` 0), spaced 1 / rate back from it."""
    if n <= 0:
        raise ValueError("a frame has at least one sample")
    if previous_ns:
        if frame_ns <= previous_ns:
            raise DecodeError("clock", f"frame time {frame_ns} ns is not after the previous frame's {previous_ns} ns")
        step = (frame_ns - previous_ns) / n
        start = previous_ns + step
    else:
        step = 1e9 / rate_hz
        start = frame_ns - step * (n - 1)
    t = np.round(start + step * np.arange(n)).astype(np.int64)
    t[-1] = frame_ns
    return t
