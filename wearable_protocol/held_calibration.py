"""A calibration held by the wearable: the WRITE_CALIBRATION command's payload and the calibration
characteristic's value (docs/protocol.md, "Calibration write-back"). All little-endian.

Payload of WRITE_CALIBRATION (56 bytes after the opcode):

    u32 calibration_id | 9 x f32 K (row-major) | 3 x f32 b (deg/s) | u32 crc32

Calibration characteristic (read, 58 bytes):

    u8 version | u8 held (0: none, 1: held) | u32 calibration_id | 9 x f32 K | 3 x f32 b | u32 crc32

``crc32`` is the CRC-32 of IEEE 802.3 (zlib's; check value 0xCBF43926 for b"123456789") over the bytes from
``calibration_id`` to the last ``b``. The parameters are those of g = K m + b (K the calibration matrix, b in
deg/s of true rate); the device keeps streaming raw readings m so that a new calibration measures the sensor,
not the previous correction.
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .codec import PROTOCOL_VERSION, DecodeError

_PARAMS = struct.Struct("<I9f3f")
PARAMS_SIZE = _PARAMS.size  # 52
PAYLOAD_SIZE = PARAMS_SIZE + 4  # 56
_SLOT_HEAD = struct.Struct("<BB")
SLOT_SIZE = _SLOT_HEAD.size + PAYLOAD_SIZE  # 58
MAX_ABS_PARAMETER = 1.0e6  # a K element or bias beyond this is not a calibration


def crc32(data: bytes) -> int:
    """CRC-32 (IEEE 802.3, reflected, init and final xor 0xFFFFFFFF)."""
    return zlib.crc32(data) & 0xFFFFFFFF


def _f32(x: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", x))[0])


@dataclass(frozen=True)
class HeldCalibration:
    """One calibration as the device holds it: the store's calibration id, K (3x3, row-major) and b, at float32."""

    calibration_id: int
    K: tuple[float, ...]  # 9 values, row-major
    b: tuple[float, float, float]

    @classmethod
    def from_parameters(cls, calibration_id: int, K: ArrayLike, b: ArrayLike) -> HeldCalibration:
        """From any 3x3 (or 3 diagonal values) K and 3 b; values are rounded to float32 as the device stores them.
        Raises ValueError for an id outside u32, a wrong shape, or a non-finite or absurd value."""
        k, b_arr = np.asarray(K, dtype=float), np.asarray(b, dtype=float)
        if k.shape == (3,):
            k = np.diag(k)
        if k.shape != (3, 3) or b_arr.shape != (3,):
            raise ValueError(f"K must be 3x3 (or 3 scale factors) and b 3 values, got shapes {k.shape} and {b_arr.shape}")
        if not 0 <= int(calibration_id) <= 0xFFFFFFFF:
            raise ValueError(f"calibration id {calibration_id} does not fit the protocol's 32 bits")
        values = [float(v) for v in k.ravel()] + [float(v) for v in b_arr]
        if not all(math.isfinite(v) and abs(v) <= MAX_ABS_PARAMETER for v in values):
            raise ValueError("K and b must be finite numbers of sensible size")
        f = [_f32(v) for v in values]
        return cls(int(calibration_id), tuple(f[:9]), (f[9], f[10], f[11]))

    def _params(self) -> bytes:
        return _PARAMS.pack(self.calibration_id, *self.K, *self.b)

    def payload(self) -> bytes:
        """The WRITE_CALIBRATION payload: parameters then their CRC-32."""
        params = self._params()
        return params + struct.pack("<I", crc32(params))

    @classmethod
    def from_payload(cls, data: bytes | bytearray) -> HeldCalibration:
        """Decode and verify a WRITE_CALIBRATION payload; DecodeError 'length', 'checksum' or 'value'."""
        if len(data) != PAYLOAD_SIZE:
            raise DecodeError("length", f"a calibration is {PAYLOAD_SIZE} bytes, got {len(data)}")
        params, (crc,) = bytes(data[:PARAMS_SIZE]), struct.unpack_from("<I", data, PARAMS_SIZE)
        if crc32(params) != crc:
            raise DecodeError("checksum", f"CRC-32 0x{crc:08x} does not match the parameters (0x{crc32(params):08x})")
        cid, *vals = _PARAMS.unpack(params)
        if not all(math.isfinite(v) and abs(v) <= MAX_ABS_PARAMETER for v in vals):
            raise DecodeError("value", "K and b must be finite numbers of sensible size")
        if abs(_det3(vals[:9])) < 1e-9:
            raise DecodeError("value", "K is singular: it cannot be a calibration")
        return cls(cid, tuple(vals[:9]), (vals[9], vals[10], vals[11]))

    def apply(self, m: tuple[float, float, float]) -> tuple[float, float, float]:
        """g = K m + b for one raw reading m (deg/s), as the device does."""
        k = self.K
        return tuple(k[3 * i] * m[0] + k[3 * i + 1] * m[1] + k[3 * i + 2] * m[2] + self.b[i]  # type: ignore[return-value]
                     for i in range(3))

    def to_dict(self) -> dict[str, object]:
        return {"calibration_id": self.calibration_id, "K": [list(self.K[i:i + 3]) for i in (0, 3, 6)], "b": list(self.b)}


def _det3(k: list[float]) -> float:
    return (k[0] * (k[4] * k[8] - k[5] * k[7]) - k[1] * (k[3] * k[8] - k[5] * k[6])
            + k[2] * (k[3] * k[7] - k[4] * k[6]))


def encode_slot(held: HeldCalibration | None) -> bytes:
    """The calibration characteristic's value: what the device holds, or 'none' (all zero after the header)."""
    if held is None:
        return _SLOT_HEAD.pack(PROTOCOL_VERSION, 0) + bytes(PAYLOAD_SIZE)
    return _SLOT_HEAD.pack(PROTOCOL_VERSION, 1) + held.payload()


def decode_slot(data: bytes | bytearray) -> HeldCalibration | None:
    """What the device says it holds (None: nothing); DecodeError when the value is malformed or corrupt."""
    if len(data) != SLOT_SIZE:
        raise DecodeError("length", f"the calibration characteristic is {SLOT_SIZE} bytes, got {len(data)}")
    version, held = _SLOT_HEAD.unpack_from(data)
    if version != PROTOCOL_VERSION:
        raise DecodeError("version", f"device speaks protocol version {version}, this client {PROTOCOL_VERSION}")
    if held == 0:
        return None
    if held != 1:
        raise DecodeError("value", f"held flag {held}, expected 0 or 1")
    return HeldCalibration.from_payload(bytes(data[_SLOT_HEAD.size:]))
