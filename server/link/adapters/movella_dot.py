"""Movella DOT: "Rate quantities" notifications, one sample each, stamped by the sensor's microsecond clock
(``wearable_protocol.vendors.movella_dot`` holds the byte layouts, the choice of payload mode and their sources).

Before a start the central writes the output rate to the Device control characteristic (it cannot change once a
measurement runs), enables the medium payload's notifications, then writes start with the payload mode to the
Control characteristic; a stop is the reverse. The time stamps (u32 microseconds, wrapping every 71.6 minutes) are
unwrapped; there is no counter, so a gap of more than one output period is counted as lost samples (a stamp at or
before the last is a duplicate; the DOT's notifications carry no checksum, so a corrupt stamp cannot be told from
a gap). The ranges
are the DOT's own (+-2000 deg/s, +-16 g); a rate at the range's end is taken as clipped. Identify writes the
Device control's identify field: the LED blinks red for 10 s. The firmware version, serial number and battery come
from the DOT's own Device info and Battery characteristics (it has no standard Device Information service).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from wearable_protocol import DecodeError, DeviceConfig
from wearable_protocol.models import MOVELLA_DOT
from wearable_protocol.vendors import movella_dot as dot

from ..base import ConnectError, LinkStats, SampleBatch
from ..rate_fit import RateFit
from .base import Adapter, fixed_range_rate, vendor_config

log = logging.getLogger(__name__)

WRAP_US = 1 << 32
CLIP_FRACTION = 0.999  # a rate this close to the range's end is clipped


class DotDecoder:
    """Rate quantities notifications to SampleBatches, times from the sensor's clock, lost samples from its gaps."""

    def __init__(self, stats: LinkStats, rate_hz: float) -> None:
        self.stats = stats
        self.rate_hz = rate_hz
        self._fit = RateFit()
        self._wraps = 0
        self._last_raw: int | None = None
        self._last_us: int | None = None
        self._t0_us: int | None = None
        self._counter = 0
        self.last_t_s: float | None = None

    def _unwrap(self, raw: int) -> int:
        if self._last_raw is not None and raw < self._last_raw and self._last_raw - raw > WRAP_US // 2:
            self._wraps += 1
        self._last_raw = raw
        return raw + self._wraps * WRAP_US

    def feed(self, data: bytes) -> SampleBatch | None:
        """One notification; its batch (None when refused or a duplicate)."""
        try:
            s = dot.decode_rate_quantities(data)
        except DecodeError as e:
            self.stats.refused(e.reason)
            return None
        t_us = self._unwrap(s.timestamp_us)
        fs = self._fit.rate(self.rate_hz)
        lost = 0
        if self._last_us is not None:
            gap_s = (t_us - self._last_us) * 1e-6
            if gap_s <= 0:
                self.stats.duplicate_packets += 1
                return None
            lost = max(0, int(round(gap_s * fs)) - 1)
        if self._t0_us is None:
            self._t0_us = t_us
        self._last_us = t_us
        self._counter += lost
        seq = np.array([self._counter], dtype=np.int64)
        self._fit.add(self._counter, t_us)
        self._counter += 1
        st = self.stats
        st.packets += 1
        st.samples += 1
        if lost:
            st.lost_samples += lost
            st.lost_packets += lost
        fs = self._fit.rate(self.rate_hz)
        st.fs_estimate_hz = fs
        t_s = np.array([(t_us - self._t0_us) * 1e-6])
        self.last_t_s = float(t_s[-1])
        saturated = np.array([bool(np.any(np.abs(s.gyro_dps) >= CLIP_FRACTION * dot.GYRO_FULL_SCALE_DPS))])
        return SampleBatch(t_s, s.gyro_dps[None, :], s.accel_g[None, :], seq, lost, fs, saturated)


class MovellaDotAdapter(Adapter):
    """A Movella DOT streaming Rate quantities."""

    model = MOVELLA_DOT
    data_char = dot.MEDIUM_PAYLOAD_CHAR

    @classmethod
    def recognises(cls, io: Any) -> bool:
        return bool(io.has(dot.CONTROL_CHAR) and io.has(dot.DEVICE_CONTROL_CHAR))

    def _setup(self) -> None:
        self._rate = int(self.model.stream_rate_hz)
        self._decoder: DotDecoder | None = None

    async def open(self) -> DeviceConfig:
        if not self.io.has(dot.DEVICE_CONTROL_CHAR):
            raise ConnectError("the device has no Movella DOT device control characteristic; is it a Movella DOT?")
        try:
            dot.DeviceControl.decode(await self.io.read(dot.DEVICE_CONTROL_CHAR))
        except DecodeError as e:
            raise ConnectError(f"the DOT's device control is unreadable ({e})") from e
        return self._config()

    def _config(self, streaming: bool = False) -> DeviceConfig:
        cfg = vendor_config(self._rate, dot.GYRO_FULL_SCALE_DPS, dot.ACCEL_RANGE_G, 1, 1.0, 1.0, streaming)
        self.config = cfg
        return cfg

    async def details(self) -> dict[str, Any]:
        """Firmware, serial number and battery from the DOT's own characteristics (read as the standard services'
        are: a field it does not give, or gives unreadable, is left out)."""
        out: dict[str, Any] = {}
        raw = await self._optional(dot.DEVICE_INFO_CHAR)
        try:
            info = dot.DeviceInfo.decode(raw) if raw else None
        except DecodeError as e:
            log.info("the DOT's device info is malformed: %s", e)
            info = None
        if info is not None:
            out.update(firmware=info.firmware, serial=str(info.serial), model=info.product_code, manufacturer="Movella")
        battery = await self._optional(dot.BATTERY_CHAR)
        if battery:
            out["battery_pct"] = int(battery[0])
        return out

    async def configure(self, *, sample_rate_hz: float | None, gyro_full_scale_dps: int | None,
                        accel_range_g: int | None) -> DeviceConfig:
        rate = fixed_range_rate(self.model, "Movella DOT", "streams", sample_rate_hz, gyro_full_scale_dps, accel_range_g)
        self._rate = self._rate if rate is None else rate
        self._decoder = None
        return self._config()

    async def identify(self, seconds: int) -> None:
        """Blink the LED (the DOT's own pattern, 10 s whatever ``seconds``)."""
        await self.io.write(dot.DEVICE_CONTROL_CHAR, dot.DeviceControl.identify_now().encode())

    async def start(self, *, resume: bool) -> None:
        await self.io.write(dot.DEVICE_CONTROL_CHAR, dot.DeviceControl.set_output_rate(self._rate).encode())
        if self._decoder is None or not resume:
            self._decoder = DotDecoder(self.stats, float(self._rate))
        await self.io.subscribe(dot.MEDIUM_PAYLOAD_CHAR, self._on_data)
        await self.io.write(dot.CONTROL_CHAR, dot.Control(1, dot.PayloadMode.RATE_QUANTITIES).encode())
        self._config(streaming=True)

    async def stop(self) -> None:
        await self.io.write(dot.CONTROL_CHAR, dot.Control(0, dot.PayloadMode.RATE_QUANTITIES).encode())
        await self.io.unsubscribe(dot.MEDIUM_PAYLOAD_CHAR)
        self._decoder = None

    def _on_data(self, data: bytes) -> None:
        if self._decoder is None:
            return
        batch = self._decoder.feed(bytes(data))
        if batch is None:
            return
        self.last_t_s = self._decoder.last_t_s
        self.sink.batch(batch)
