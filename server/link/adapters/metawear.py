"""MbientLab MetaWear (MetaMotion): BMI160 gyroscope and accelerometer in packed notifications
(``wearable_protocol.vendors.metawear`` holds the byte layouts and their sources).

MetaWear commands have no reply and its streamed data carry no counter and no time stamp: sample
times are arrival times (``arrival.ArrivalTimeline``) and lost samples cannot be detected. Each packed
gyroscope notification is paired with the accelerometer notification that follows it; when one is
missing the latest accelerometer reading is held.
"""

from __future__ import annotations

import numpy as np

from wearable_protocol import DecodeError, DeviceConfig
from wearable_protocol.models import METAWEAR
from wearable_protocol.vendors import metawear as mw

from ..base import CommandError, ConnectError
from .arrival import ArrivalTimeline
from .base import Adapter, vendor_config

INT16_LIMITS = (-32768, 32767)


class MetaWearAdapter(Adapter):
    """A MetaWear board's gyroscope and accelerometer, streamed packed."""

    model = METAWEAR
    data_char = mw.NOTIFY_CHAR

    def _setup(self) -> None:
        self._rate = self.model.stream_rate_hz
        self._gyro_range = self.model.gyro_range_dps
        self._acc_range = self.model.accel_range_g
        self._timeline: ArrivalTimeline | None = None
        self._gyro: tuple[float, np.ndarray] | None = None  # (arrival, counts) waiting for its accelerometer pair
        self._acc = np.array([0.0, 0.0, 1.0])

    async def open(self) -> DeviceConfig:
        if not self.io.has(mw.COMMAND_CHAR):
            raise ConnectError("the device has no MetaWear command characteristic; is it a MetaMotion board?")
        await self.io.subscribe(mw.NOTIFY_CHAR, self._on_notify)
        return self._config()

    def _config(self, streaming: bool = False) -> DeviceConfig:
        cfg = vendor_config(self._rate, self._gyro_range, self._acc_range, 3, mw.GYRO_RANGES[self._gyro_range][1],
                            mw.ACC_RANGES[self._acc_range][1], streaming)
        self.config = cfg
        return cfg

    async def configure(self, *, sample_rate_hz: float | None, gyro_full_scale_dps: int | None,
                        accel_range_g: int | None) -> DeviceConfig:
        if sample_rate_hz is not None and (float(sample_rate_hz) not in mw.GYRO_ODR or float(sample_rate_hz) not in mw.ACC_ODR):
            both = sorted(set(mw.GYRO_ODR) & set(mw.ACC_ODR))
            raise CommandError(f"the MetaWear gyroscope and accelerometer share no rate {sample_rate_hz:g} Hz: choose one of "
                               + ", ".join(f"{r:g}" for r in both))
        if gyro_full_scale_dps is not None and int(gyro_full_scale_dps) not in mw.GYRO_RANGES:
            raise CommandError(f"the BMI160 has no gyro range {gyro_full_scale_dps}: choose one of "
                               + ", ".join(str(r) for r in sorted(mw.GYRO_RANGES)))
        if accel_range_g is not None and int(accel_range_g) not in mw.ACC_RANGES:
            raise CommandError(f"the BMI160 has no accelerometer range {accel_range_g} g: choose one of "
                               + ", ".join(str(r) for r in mw.ACC_RANGES))
        self._rate = float(sample_rate_hz) if sample_rate_hz is not None else self._rate
        self._gyro_range = int(gyro_full_scale_dps) if gyro_full_scale_dps is not None else self._gyro_range
        self._acc_range = int(accel_range_g) if accel_range_g is not None else self._acc_range
        self._timeline = None
        return self._config()

    async def _send(self, *commands: bytes) -> None:
        for c in commands:
            await self.io.write(mw.COMMAND_CHAR, c, response=False)

    async def identify(self, seconds: int) -> None:
        await self._send(*mw.led_blink(seconds))

    async def start(self, *, resume: bool) -> None:
        G, A = mw.Module.GYROSCOPE, mw.Module.ACCELEROMETER
        # the timeline knows of the gap before the commands go: the first readings may come while they are still sent
        cfg = self._config(streaming=True)
        if self._timeline is None:
            self._timeline = ArrivalTimeline(self.stats, cfg.sample_rate_hz)
        self._timeline.begin(resume)
        self._gyro = None
        await self._send(
            mw.gyro_config(self._rate, self._gyro_range), mw.accel_config(self._rate, self._acc_range),
            mw.subscribe(G, mw.Register.GYRO_PACKED), mw.subscribe(A, mw.Register.ACC_PACKED),
            mw.data_enable(G, True), mw.data_enable(A, True), mw.power(A, True), mw.power(G, True),
        )

    async def stop(self) -> None:
        G, A = mw.Module.GYROSCOPE, mw.Module.ACCELEROMETER
        await self._send(mw.power(G, False), mw.power(A, False), mw.data_enable(G, False), mw.data_enable(A, False),
                         mw.subscribe(G, mw.Register.GYRO_PACKED, False), mw.subscribe(A, mw.Register.ACC_PACKED, False))
        self._timeline = None

    def _on_notify(self, data: bytes) -> None:
        try:
            note = mw.decode_notification(bytes(data))
        except DecodeError as e:
            self.stats.refused(e.reason)
            return
        now = self.clock()
        if note.module == mw.Module.GYROSCOPE:
            if self._gyro is not None:  # its accelerometer notification never came: hold the last reading
                self._emit(*self._gyro, np.tile(self._acc, (len(self._gyro[1]), 1)))
            self._gyro = (now, note.counts)
            return
        acc = mw.accel_g(note.counts, self._acc_range)
        self._acc = acc[-1]
        if self._gyro is not None:
            arrival, counts = self._gyro
            self._gyro = None
            self._emit(arrival, counts, acc if len(acc) == len(counts) else np.tile(acc[-1], (len(counts), 1)))

    def _emit(self, arrival: float, counts: np.ndarray, accel: np.ndarray) -> None:
        if self._timeline is None:
            return
        saturated = ((counts == INT16_LIMITS[0]) | (counts == INT16_LIMITS[1])).any(axis=1)
        batch = self._timeline.place(arrival, mw.gyro_dps(counts, self._gyro_range), accel, saturated)
        self.last_t_s = self._timeline.last_t_s
        self.sink.batch(batch)
