"""A simulated MbientLab MetaMotion: MetaWear commands, BMI160 gyroscope and accelerometer, packed data."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from typing import Any

import numpy as np

import wearable_protocol as wp
from wearable_protocol.models import METAWEAR
from wearable_protocol.vendors import metawear as mw

from ..sources import SampleSource
from ..streaming import WearableSession
from ..wearable import Wearable

PACKED = 3  # samples per packed notification


class MetaWearWearable(Wearable):
    """A MetaWear board: commands without replies; three gyroscope samples and three accelerometer samples
    per packed notification pair, no counter, no time stamp. The gyroscope's power command starts the
    session and stops it."""

    model = METAWEAR
    data_char = mw.NOTIFY_CHAR
    gatt_services = mw.SERVICES

    def __init__(self, source: SampleSource, **kwargs: Any) -> None:
        super().__init__(source, **kwargs)
        self._subscribed: set[tuple[int, int]] = set()
        self._enabled: set[int] = set()
        self._led_pattern_s = 0.0  # how long the LED pattern written last blinks (s)

    def _default_name(self) -> str:
        return "MetaWear"

    @property
    def samples_per_packet(self) -> int:
        return PACKED

    device_information = (b"MbientLab Inc", b"5", b"1.7.3")  # model number 5: MetaMotion S

    def _readable(self) -> dict[str, Callable[[], bytes]]:
        return {}

    def write(self, char_uuid: str, data: bytes) -> None:
        if char_uuid != mw.COMMAND_CHAR:
            raise wp.GattError("not_permitted", "Write not permitted")
        if len(data) < 3:
            return  # MetaWear ignores what it does not understand; it never replies to commands
        module, register = data[0], data[1]
        if module == mw.Module.LED:
            self._led(bytes(data))
            return
        if module not in (mw.Module.GYROSCOPE, mw.Module.ACCELEROMETER):
            return
        if register == mw.Register.CONFIG:
            self._configure(bytes(data))
        elif register in (mw.Register.GYRO_PACKED, mw.Register.ACC_PACKED, mw.Register.GYRO_DATA, mw.Register.ACC_DATA):
            (self._subscribed.add if data[2] else self._subscribed.discard)((module, register))
        elif register == mw.Register.DATA_ENABLE:
            (self._enabled.add if data[2] else self._enabled.discard)(module)
        elif register == mw.Register.POWER and module == mw.Module.GYROSCOPE:
            if data[2]:
                self._start()
            else:
                self._end_session("stopped by the central")

    def _led(self, data: bytes) -> None:
        """The LED module: a pattern is kept, played (the simulated LED blinks for its repeats), or stopped."""
        if data[1] == mw.LedRegister.PATTERN:
            with contextlib.suppress(wp.DecodeError):
                _, pulse_ms, repeat = mw.parse_led_pattern(data)
                self._led_pattern_s = pulse_ms * repeat / 1000.0
        elif data[1] == mw.LedRegister.PLAY and data[2] and self._led_pattern_s:
            self.identify_until = time.monotonic() + self._led_pattern_s
            self.stats.identified += 1
            self._log(f"identify: LED blinking for {self._led_pattern_s:g} s")
        elif data[1] == mw.LedRegister.STOP:
            self.identify_until = 0.0
            self._led_pattern_s = 0.0

    def _configure(self, data: bytes) -> None:
        try:
            module, rate, full = mw.parse_config(data)
        except wp.DecodeError:
            return
        if module == mw.Module.GYROSCOPE:
            self._set_sensor(rate, full)
        else:
            self.accel_range_g = full

    def _send(self, s: WearableSession, j: int) -> None:
        i0, i1 = j * s.n, (j + 1) * s.n
        blk = self.source.block(i0, i1)
        assert self._central is not None
        G, A = mw.Module.GYROSCOPE, mw.Module.ACCELEROMETER
        s.sent_any = True
        self.stats.packets_sent += 1
        if (G, mw.Register.GYRO_PACKED) in self._subscribed and G in self._enabled:
            counts = np.round(blk.gyro * mw.GYRO_RANGES[self.gyro_full_scale_dps][1])
            note = mw.encode_notification(G, counts)
            if self._corrupt_pending > 0:
                self._corrupt_pending -= 1
                self.stats.packets_corrupted += 1
                note = note[:-1]
            self._central.notify(mw.NOTIFY_CHAR, note)
        if (A, mw.Register.ACC_PACKED) in self._subscribed and A in self._enabled:
            counts = np.round(blk.accel * mw.ACC_RANGES[self.accel_range_g][1])
            self._central.notify(mw.NOTIFY_CHAR, mw.encode_notification(A, counts))
