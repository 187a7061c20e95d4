"""Nordic Thingy:52 Motion service: one raw sample (accelerometer, gyroscope, compass) per notification
(``wearable_protocol.vendors.thingy52`` holds the byte layouts and their sources).

The central writes the motion processing frequency to the configuration characteristic; the sensor
streams while the raw-data notifications are enabled. No counter and no time stamp: sample times are
arrival times (``arrival.ArrivalTimeline``) and lost samples cannot be detected. The gyroscope's range
is fixed at +-2000 deg/s and its resolution is 1/32 deg/s.
"""

from __future__ import annotations

import asyncio
import contextlib

import numpy as np

from wearable_protocol import DecodeError, DeviceConfig
from wearable_protocol.models import THINGY52
from wearable_protocol.vendors import thingy52 as th

from ..base import CommandError, ConnectError
from .arrival import ArrivalTimeline
from .base import Adapter, fixed_range_rate, vendor_config

GYRO_LIMIT_DPS = 32767 / (1 << th.GYRO_FRACTION_BITS)


class Thingy52Adapter(Adapter):
    """A Thingy:52's raw motion data."""

    model = THINGY52
    data_char = th.RAW_DATA_CHAR

    def _setup(self) -> None:
        self._rate = int(self.model.stream_rate_hz)
        self._motion = th.MotionConfig()
        self._timeline: ArrivalTimeline | None = None
        self._restore: asyncio.Task[None] | None = None  # puts the LED back after an identify
        self._led_before = b""

    async def open(self) -> DeviceConfig:
        if not self.io.has(th.CONFIG_CHAR):
            raise ConnectError("the device has no Thingy:52 motion configuration; is it a Thingy:52?")
        try:
            self._motion = th.MotionConfig.decode(await self.io.read(th.CONFIG_CHAR))
        except DecodeError as e:
            raise ConnectError(f"the Thingy:52's motion configuration is unreadable ({e})") from e
        return self._config()

    def _config(self, streaming: bool = False) -> DeviceConfig:
        cfg = vendor_config(self._rate, th.GYRO_FULL_SCALE_DPS, self.model.accel_range_g, 1,
                            float(1 << th.GYRO_FRACTION_BITS), float(1 << th.ACCEL_FRACTION_BITS), streaming)
        self.config = cfg
        return cfg

    async def configure(self, *, sample_rate_hz: float | None, gyro_full_scale_dps: int | None,
                        accel_range_g: int | None) -> DeviceConfig:
        rate = fixed_range_rate(self.model, "Thingy:52", "processes motion", sample_rate_hz, gyro_full_scale_dps, accel_range_g)
        self._rate = self._rate if rate is None else rate
        self._timeline = None
        return self._config()

    async def identify(self, seconds: int) -> None:
        """Breathe the LED green for ``seconds``, then put back what it showed (read first)."""
        if not self.io.has(th.LED_CHAR):
            raise CommandError("this Thingy:52's firmware has no User Interface service: its LED cannot be set")
        before = await self.io.read(th.LED_CHAR)
        await self.io.write(th.LED_CHAR, th.led_breathe())
        if self._restore is not None:
            self._restore.cancel()  # a second identify: the first one's LED value stays the one to put back
            before = self._led_before
        self._led_before = before
        self._restore = asyncio.get_running_loop().create_task(self._restore_led(seconds))

    async def _restore_led(self, seconds: int) -> None:
        await asyncio.sleep(seconds)
        with contextlib.suppress(Exception):  # the link may be gone: the Thingy keeps breathing until told
            await self.io.write(th.LED_CHAR, self._led_before)
        self._restore = None

    async def start(self, *, resume: bool) -> None:
        self._motion = th.MotionConfig(self._motion.pedometer_interval_ms, self._motion.temperature_interval_ms,
                                       self._motion.compass_interval_ms, self._rate, self._motion.wake_on_motion)
        await self.io.write(th.CONFIG_CHAR, self._motion.encode())
        cfg = self._config(streaming=True)
        if self._timeline is None:
            self._timeline = ArrivalTimeline(self.stats, cfg.sample_rate_hz)
        self._timeline.begin(resume)
        await self.io.subscribe(th.RAW_DATA_CHAR, self._on_raw)

    async def stop(self) -> None:
        await self.io.unsubscribe(th.RAW_DATA_CHAR)
        self._timeline = None

    def _on_raw(self, data: bytes) -> None:
        now = self.clock()
        try:
            raw = th.decode_raw(bytes(data))
        except DecodeError as e:
            self.stats.refused(e.reason)
            return
        if self._timeline is None:
            return
        gyro = raw.gyro_dps[None, :]
        saturated = (np.abs(gyro) >= GYRO_LIMIT_DPS).any(axis=1)
        batch = self._timeline.place(now, gyro, raw.accel_g[None, :], saturated)
        self.last_t_s = self._timeline.last_t_s
        self.sink.batch(batch)
