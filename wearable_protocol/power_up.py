"""The wearable's power-up and temperature: the power-up characteristic's value (docs/protocol.md,
"Power-up and temperature"). All little-endian.

Power-up characteristic (read, 12 bytes):

    u8 version | u8 flags | u32 boot_count | u32 uptime_s | i16 temperature (0.01 degC)

``flags`` bit 0: ``boot_count`` is kept (a counter of power-ups in non-volatile memory; without it the
power-up is dated by its start, the read time minus ``uptime_s``); bit 1: ``temperature`` is valid (the
IMU's own temperature sensor). A calibration measured in one power-up, or at another temperature, does
not hold for the next (the paper, section 1): the central records both with each calibration.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from enum import IntFlag

from .codec import PROTOCOL_VERSION, DecodeError

_POWER_UP = struct.Struct("<BBIIh")
POWER_UP_SIZE = _POWER_UP.size  # 12
TEMPERATURE_STEP_C = 0.01
UINT32_MAX = 0xFFFFFFFF


class PowerUpFlags(IntFlag):
    """Bits of the power-up characteristic's flags byte."""

    BOOT_COUNT = 0x01
    TEMPERATURE = 0x02


@dataclass(frozen=True)
class PowerUp:
    """The device's power-up (its boot count when it keeps one, the seconds since it started) and temperature."""

    boot_count: int | None
    uptime_s: int
    temperature_c: float | None = None

    def encode(self) -> bytes:
        """The characteristic's 12 bytes; raises ValueError for a value the fields cannot carry."""
        if self.boot_count is not None and not 0 <= self.boot_count <= UINT32_MAX:
            raise ValueError(f"boot count {self.boot_count} does not fit 32 bits")
        if not 0 <= self.uptime_s <= UINT32_MAX:
            raise ValueError(f"uptime {self.uptime_s} s does not fit 32 bits")
        flags = PowerUpFlags(0)
        centi = 0
        if self.boot_count is not None:
            flags |= PowerUpFlags.BOOT_COUNT
        if self.temperature_c is not None:
            if not math.isfinite(self.temperature_c) or not -327.68 <= self.temperature_c <= 327.67:
                raise ValueError(f"temperature {self.temperature_c} degC is outside -327.68..327.67")
            flags |= PowerUpFlags.TEMPERATURE
            centi = round(self.temperature_c / TEMPERATURE_STEP_C)
        return _POWER_UP.pack(PROTOCOL_VERSION, int(flags), self.boot_count or 0, self.uptime_s, centi)

    @classmethod
    def decode(cls, data: bytes | bytearray) -> PowerUp:
        """Decode the characteristic's value; DecodeError 'length', 'version' or 'flags' when malformed."""
        if len(data) != POWER_UP_SIZE:
            raise DecodeError("length", f"the power-up characteristic is {len(data)} bytes, expected {POWER_UP_SIZE}")
        version, flags, boot_count, uptime_s, centi = _POWER_UP.unpack(bytes(data))
        if version != PROTOCOL_VERSION:
            raise DecodeError("version", f"device speaks protocol version {version}, this client {PROTOCOL_VERSION}")
        if flags & ~int(PowerUpFlags.BOOT_COUNT | PowerUpFlags.TEMPERATURE):
            raise DecodeError("flags", f"unknown power-up flags 0x{flags:02x}")
        return cls(
            boot_count if flags & PowerUpFlags.BOOT_COUNT else None,
            uptime_s,
            round(centi * TEMPERATURE_STEP_C, 2) if flags & PowerUpFlags.TEMPERATURE else None,
        )
