"""A simulated Nordic Thingy:52: the Motion service's configuration and raw-data characteristics."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import wearable_protocol as wp
from wearable_protocol.models import THINGY52
from wearable_protocol.vendors import thingy52 as th

from ..sources import SampleSource
from ..streaming import WearableSession
from ..wearable import Wearable

IDLE_LED = bytes([1, 0, 0, 8])  # the simulated Thingy's LED at rest: constant, a dim blue


class Thingy52Wearable(Wearable):
    """A Thingy:52 streaming one raw sample per notification while the central listens to the raw data."""

    model = THINGY52
    data_char = th.RAW_DATA_CHAR
    gatt_services = th.SERVICES

    def __init__(self, source: SampleSource, **kwargs: Any) -> None:
        super().__init__(source, **kwargs)
        self.gyro_full_scale_dps = th.GYRO_FULL_SCALE_DPS
        self.accel_range_g = THINGY52.accel_range_g
        self.motion = th.MotionConfig(motion_freq_hz=int(self.rate_hz))
        self.led = IDLE_LED  # the LED characteristic's value

    def _default_name(self) -> str:
        return "Thingy"

    @property
    def samples_per_packet(self) -> int:
        return 1

    def _readable(self) -> dict[str, Callable[[], bytes]]:
        # the Thingy has no Device Information service (its GATT table leaves it out); battery comes from the base
        return {th.CONFIG_CHAR: lambda: self.motion.encode(), th.DEVICE_NAME_CHAR: lambda: self.name.encode(),
                th.LED_CHAR: lambda: self.led}

    @property
    def identifying(self) -> bool:
        """Whether the LED breathes, as a central asks to tell this Thingy from the others."""
        return self.led[0] == th.LED_MODE_BREATHE

    def write(self, char_uuid: str, data: bytes) -> None:
        if char_uuid == th.DEVICE_NAME_CHAR:
            self.name = bytes(data).decode("utf-8", "replace")[:10]
            return
        if char_uuid == th.LED_CHAR:
            try:
                self.led = th.check_led(bytes(data))
            except wp.DecodeError as e:
                raise wp.GattError("invalid_value", str(e)) from e
            self.stats.identified += int(self.identifying)
            return
        if char_uuid != th.CONFIG_CHAR:
            raise wp.GattError("not_permitted", "Write not permitted")
        try:
            motion = th.MotionConfig.decode(bytes(data))
        except wp.DecodeError as e:
            raise wp.GattError("invalid_value", str(e)) from e
        self._set_sensor(float(motion.motion_freq_hz))
        self.motion = motion

    def set_notify(self, char_uuid: str, enabled: bool) -> None:
        super().set_notify(char_uuid, enabled)
        if char_uuid != th.RAW_DATA_CHAR:
            return
        if enabled:
            self._start()
        else:
            self._end_session("raw data notifications disabled")

    def _send(self, s: WearableSession, j: int) -> None:
        blk = self.source.block(j, j + 1)
        assert self._central is not None
        note = th.encode_raw(blk.accel[0], blk.gyro[0])
        if self._corrupt_pending > 0:
            self._corrupt_pending -= 1
            self.stats.packets_corrupted += 1
            note = note[:-2]
        s.sent_any = True
        self.stats.packets_sent += 1
        self._central.notify(th.RAW_DATA_CHAR, note)
