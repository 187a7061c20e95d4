"""Binary encodings of the gyrocal wearable protocol (see docs/protocol.md). All little-endian.

Data packet (IMU data characteristic, notify), 10-byte header then N samples of 12 bytes:

    u8 version | u8 flags | u8 N | u8 config_id | u16 seq | u32 t_first_us | N x (i16 gx gy gz ax ay az)

Config (IMU config characteristic, read), 20 bytes:

    u8 version | u8 config_id | f32 rate_hz | u16 gyro_fs_dps | u8 accel_range_g | u8 N |
    f32 gyro_lsb_per_dps | f32 accel_lsb_per_g | u8 state | u8 reserved

Control (IMU control characteristic): a write is ``u8 opcode`` + payload; every write is answered by
a status notification ``u8 opcode | u8 status | u8 config_id`` on the same characteristic.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from enum import IntEnum, IntFlag

import numpy as np

from .sensor import DEFAULT_MTU, INT16_MAX, INT16_MIN, MAX_NOTIFICATIONS_PER_S

PROTOCOL_VERSION = 1

_HEADER = struct.Struct("<BBBBHI")
HEADER_SIZE = _HEADER.size  # 10
SAMPLE_SIZE = 12  # six int16
SEQ_MODULUS = 1 << 16
CLOCK_MODULUS = 1 << 32  # device clock in microseconds wraps after ~71.6 min


class DecodeError(ValueError):
    """Bytes that are not a valid message of this protocol; ``reason`` is a short machine tag."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


class PacketFlags(IntFlag):
    """Bits of the packet header's flags byte."""

    SESSION_START = 0x01  # first packet of a new streaming session: seq and sample counter start at 0
    RESUMED = 0x02  # first packet sent after the central reconnected and resumed the session
    GYRO_CLIPPED = 0x04  # at least one gyro value of this packet is at the int16 limit (saturated)


@dataclass(frozen=True, eq=False)
class Packet:
    """One decoded data packet: header fields and the raw int16 samples, shape (N, 6)."""

    version: int
    flags: PacketFlags
    config_id: int
    seq: int
    t_first_us: int
    raw: np.ndarray  # (N, 6) int16: gx, gy, gz, ax, ay, az in counts

    @property
    def n(self) -> int:
        return int(self.raw.shape[0])


def encode_packet(seq: int, t_first_us: int, raw: np.ndarray, flags: int = 0, config_id: int = 0) -> bytes:
    """Encode one packet; ``raw`` is (N, 6) int16 counts (use :func:`quantize`)."""
    raw = np.asarray(raw)
    if raw.ndim != 2 or raw.shape[1] != 6 or not 1 <= raw.shape[0] <= 255:
        raise ValueError(f"raw samples must have shape (N, 6) with 1 <= N <= 255, got {raw.shape}")
    header = _HEADER.pack(PROTOCOL_VERSION, int(flags) & 0xFF, raw.shape[0], config_id & 0xFF,
                          seq % SEQ_MODULUS, t_first_us % CLOCK_MODULUS)
    return header + raw.astype("<i2", copy=False).tobytes()


def decode_packet(data: bytes | bytearray | memoryview, expected_n: int | None = None) -> Packet:
    """Decode one packet. Raises DecodeError (never anything else) for malformed bytes."""
    size = len(data)
    if size < HEADER_SIZE + SAMPLE_SIZE:
        raise DecodeError("short", f"{size} bytes, a packet has at least {HEADER_SIZE + SAMPLE_SIZE}")
    version, flags, n, config_id, seq, t_us = _HEADER.unpack_from(data)
    if version != PROTOCOL_VERSION:
        raise DecodeError("version", f"packet version {version}, this client speaks {PROTOCOL_VERSION}")
    if n == 0 or size != HEADER_SIZE + n * SAMPLE_SIZE:
        raise DecodeError("length", f"{size} bytes for N={n} samples (expected {HEADER_SIZE + n * SAMPLE_SIZE})")
    if expected_n is not None and n != expected_n:
        raise DecodeError("n_mismatch", f"N={n} but the configuration says {expected_n}")
    if flags & ~int(PacketFlags.SESSION_START | PacketFlags.RESUMED | PacketFlags.GYRO_CLIPPED):
        raise DecodeError("flags", f"reserved flag bits set (0x{flags:02x})")
    raw = np.frombuffer(data, dtype="<i2", count=6 * n, offset=HEADER_SIZE).reshape(n, 6)
    return Packet(version, PacketFlags(flags), config_id, seq, t_us, raw)


def quantize(gyro_dps: np.ndarray, accel_g: np.ndarray, gyro_lsb_per_dps: float,
             accel_lsb_per_g: float) -> tuple[np.ndarray, np.ndarray]:
    """Physical values to int16 counts, (n, 6), saturating at the int16 limits as a sensor does.

    Returns the counts and a boolean (n,) mask of samples whose gyro is at a limit (clipped).
    """
    gyro_dps = np.asarray(gyro_dps, dtype=float)
    scaled = np.empty((gyro_dps.shape[0], 6))
    np.multiply(gyro_dps, gyro_lsb_per_dps, out=scaled[:, :3])
    np.multiply(np.asarray(accel_g, dtype=float), accel_lsb_per_g, out=scaled[:, 3:])
    np.rint(scaled, out=scaled)
    np.clip(scaled, INT16_MIN, INT16_MAX, out=scaled)
    counts = scaled.astype(np.int16)
    clipped = np.any((counts[:, :3] >= INT16_MAX) | (counts[:, :3] <= INT16_MIN), axis=1)
    return counts, clipped


class DeviceState(IntFlag):
    """Bits of the config's state byte."""

    STREAMING = 0x01
    SESSION_ACTIVE = 0x02  # a session exists (it survives a link loss until STOP)
    REPLAY = 0x04  # the device replays a recording: its rate and ranges are fixed


_CONFIG = struct.Struct("<BBfHBBffBB")


def _f32(x: float) -> float:
    """A float32 field as the decimal it was written from (float32 holds 7 significant digits)."""
    return float(f"{x:.7g}")
CONFIG_SIZE = _CONFIG.size  # 20


@dataclass(frozen=True)
class DeviceConfig:
    """The device's configuration as read from the config characteristic."""

    config_id: int
    sample_rate_hz: float  # nominal output data rate
    gyro_full_scale_dps: int
    accel_range_g: int
    samples_per_packet: int
    gyro_lsb_per_dps: float
    accel_lsb_per_g: float
    state: DeviceState = DeviceState(0)
    version: int = PROTOCOL_VERSION

    def encode(self) -> bytes:
        return _CONFIG.pack(self.version, self.config_id & 0xFF, self.sample_rate_hz, self.gyro_full_scale_dps,
                            self.accel_range_g, self.samples_per_packet, self.gyro_lsb_per_dps,
                            self.accel_lsb_per_g, int(self.state), 0)

    @classmethod
    def decode(cls, data: bytes | bytearray) -> DeviceConfig:
        """Decode the config characteristic's value; raises DecodeError when malformed."""
        if len(data) != CONFIG_SIZE:
            raise DecodeError("length", f"config is {len(data)} bytes, expected {CONFIG_SIZE}")
        version, cid, rate, gfs, arange, n, gsens, asens, state, _ = _CONFIG.unpack(bytes(data))
        if version != PROTOCOL_VERSION:
            raise DecodeError("version", f"device speaks protocol version {version}, this client {PROTOCOL_VERSION}")
        if not (rate > 0 and n >= 1 and gsens > 0 and asens > 0 and gfs > 0):
            raise DecodeError("value", f"config has impossible values (rate {rate}, N {n}, sensitivity {gsens})")
        return cls(cid, _f32(rate), gfs, arange, n, _f32(gsens), _f32(asens), DeviceState(state), version)

    def to_dict(self) -> dict[str, object]:
        return {
            "config_id": self.config_id, "sample_rate_hz": self.sample_rate_hz,
            "gyro_full_scale_dps": self.gyro_full_scale_dps, "accel_range_g": self.accel_range_g,
            "samples_per_packet": self.samples_per_packet, "gyro_lsb_per_dps": self.gyro_lsb_per_dps,
            "accel_lsb_per_g": self.accel_lsb_per_g, "streaming": bool(self.state & DeviceState.STREAMING),
            "protocol_version": self.version,
        }


class Opcode(IntEnum):
    """Control commands (first byte of a control write)."""

    START = 0x01  # start streaming; resumes the current session if one survived a link loss
    STOP = 0x02  # stop streaming and end the session
    SET_RATE = 0x03  # payload f32 Hz, one of SUPPORTED_RATES_HZ
    SET_GYRO_RANGE = 0x04  # payload u16 deg/s full scale
    SET_ACCEL_RANGE = 0x05  # payload u8 g
    WRITE_CALIBRATION = 0x06  # payload: a calibration with its CRC-32 (wearable_protocol.held_calibration)
    CLEAR_CALIBRATION = 0x07  # forget the held calibration
    IDENTIFY = 0x08  # payload u8 s (1..IDENTIFY_MAX_S): blink the LED or buzz that long; obeyed while streaming too
    STREAM_END = 0x10  # device -> central only: the stream ended by itself (replay finished)


class Status(IntEnum):
    """Status byte of a control reply."""

    OK = 0
    UNKNOWN_OPCODE = 1
    INVALID_VALUE = 2
    BUSY = 3  # configuration cannot change while streaming: STOP first
    BAD_LENGTH = 4
    NOT_SUPPORTED = 5  # e.g. a replaying device cannot change its rate
    CHECKSUM = 6  # a written calibration's CRC-32 does not match its bytes: nothing was applied


_PAYLOAD = {Opcode.START: "", Opcode.STOP: "", Opcode.SET_RATE: "<f", Opcode.SET_GYRO_RANGE: "<H",
            Opcode.SET_ACCEL_RANGE: "<B", Opcode.WRITE_CALIBRATION: "<56s", Opcode.CLEAR_CALIBRATION: "",
            Opcode.IDENTIFY: "<B"}
IDENTIFY_MAX_S = 60  # the longest IDENTIFY a central may ask for (s)


@dataclass(frozen=True)
class Command:
    """A control command and its argument (None for START/STOP/CLEAR_CALIBRATION; the payload bytes for
    WRITE_CALIBRATION)."""

    opcode: Opcode
    value: float | int | bytes | None = None

    def encode(self) -> bytes:
        fmt = _PAYLOAD[self.opcode]
        return bytes([self.opcode]) + (struct.pack(fmt, self.value) if fmt else b"")

    @classmethod
    def decode(cls, data: bytes | bytearray) -> Command:
        """Raises DecodeError with reason 'opcode' or 'length'."""
        if not data:
            raise DecodeError("length", "empty control write")
        try:
            op = Opcode(data[0])
            fmt = _PAYLOAD[op]
        except (ValueError, KeyError):
            raise DecodeError("opcode", f"unknown opcode 0x{data[0]:02x}") from None
        size = struct.calcsize(fmt) if fmt else 0
        if len(data) != 1 + size:
            raise DecodeError("length", f"{op.name} takes {size} payload bytes, got {len(data) - 1}")
        return cls(op, struct.unpack(fmt, bytes(data[1:]))[0] if fmt else None)


_STATUS = struct.Struct("<BBB")


@dataclass(frozen=True)
class StatusReply:
    """The device's answer to a control write (or an unsolicited STREAM_END)."""

    opcode: int
    status: Status
    config_id: int

    def encode(self) -> bytes:
        return _STATUS.pack(self.opcode, self.status, self.config_id & 0xFF)

    @classmethod
    def decode(cls, data: bytes | bytearray) -> StatusReply:
        if len(data) != _STATUS.size:
            raise DecodeError("length", f"status reply is {len(data)} bytes, expected {_STATUS.size}")
        op, status, cid = _STATUS.unpack(bytes(data))
        try:
            return cls(op, Status(status), cid)
        except ValueError:
            raise DecodeError("status", f"unknown status code {status}") from None


def max_samples_per_packet(mtu: int = DEFAULT_MTU) -> int:
    """The most samples one notification can carry at this ATT MTU (payload = MTU - 3 bytes)."""
    return max(0, (mtu - 3 - HEADER_SIZE) // SAMPLE_SIZE)


def samples_per_packet(rate_hz: float, mtu: int = DEFAULT_MTU) -> int:
    """N for a rate: the fewest samples per packet that keep notifications at <= 40 per second,
    capped by what fits the MTU (104 Hz -> 3, 34.7/s; 562.5 Hz -> 15, 37.5/s at MTU 247)."""
    cap = max_samples_per_packet(mtu)
    if cap < 1:
        raise ValueError(f"ATT MTU {mtu} is too small for one sample; the protocol needs an MTU of at least 25")
    return int(min(cap, max(1, math.ceil(rate_hz / MAX_NOTIFICATIONS_PER_S - 1e-9))))
