"""A simulated Movella DOT: its Configuration, Measurement and Battery services, streaming Rate quantities."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import wearable_protocol as wp
from wearable_protocol.models import MOVELLA_DOT
from wearable_protocol.vendors import movella_dot as dot

from ..sources import SampleSource
from ..streaming import WearableSession
from ..wearable import Wearable


class MovellaDotWearable(Wearable):
    """A DOT streaming one Rate quantities sample per notification on the medium payload characteristic, stamped
    with its microsecond clock (u32, wrapping), from the Control characteristic's start to its stop."""

    model = MOVELLA_DOT
    data_char = dot.MEDIUM_PAYLOAD_CHAR
    gatt_services = dot.SERVICES

    def __init__(self, source: SampleSource, **kwargs: Any) -> None:
        super().__init__(source, **kwargs)
        self.gyro_full_scale_dps = dot.GYRO_FULL_SCALE_DPS
        self.accel_range_g = dot.ACCEL_RANGE_G
        self.device_control = dot.DeviceControl(output_rate_hz=int(self.rate_hz) if int(self.rate_hz) in
                                                dot.STREAMING_RATES_HZ else 60)
        self.measuring = dot.Control(0, dot.PayloadMode.RATE_QUANTITIES)

    def _default_name(self) -> str:
        return dot.NAME

    @property
    def samples_per_packet(self) -> int:
        return 1

    def _info(self) -> bytes:
        mac = bytes(int(b, 16) for b in reversed(self.address.split(":")))
        return dot.DeviceInfo(mac, (2, 6, 0), (2023, 7, 1, 12, 0, 0), 0x0103, 1_000_000 + self.seed, "XS-T02").encode()

    def _readable(self) -> dict[str, Callable[[], bytes]]:
        # no standard Device Information service: the DOT's own Device info and Battery characteristics
        return {dot.DEVICE_INFO_CHAR: self._info, dot.DEVICE_CONTROL_CHAR: lambda: self.device_control.encode(),
                dot.CONTROL_CHAR: lambda: self.measuring.encode(), dot.BATTERY_CHAR: lambda: bytes([self.battery_pct, 0])}

    def write(self, char_uuid: str, data: bytes) -> None:
        if char_uuid == dot.DEVICE_CONTROL_CHAR:
            self._device_control(bytes(data))
        elif char_uuid == dot.CONTROL_CHAR:
            self._control(bytes(data))
        else:
            raise wp.GattError("not_permitted", "Write not permitted")

    def _device_control(self, data: bytes) -> None:
        try:
            asked = dot.DeviceControl.decode(data)
        except wp.DecodeError as e:
            raise wp.GattError("invalid_value", str(e)) from e
        if asked.visit & dot.VISIT_IDENTIFY and asked.identify == 1:
            self.identify_until = time.monotonic() + dot.IDENTIFY_S / self.speed
            self.stats.identified += 1
            self._log("identify: LED blinking red")
        if asked.visit & dot.VISIT_OUTPUT_RATE:
            if asked.output_rate_hz not in dot.STREAMING_RATES_HZ:
                raise wp.GattError("invalid_value", f"output rate {asked.output_rate_hz} Hz is not a streaming rate")
            if self.measuring.action == 1:
                raise wp.GattError("not_permitted", "the output rate cannot change while measuring")
            self._set_sensor(float(asked.output_rate_hz))
            self.device_control = dot.DeviceControl(output_rate_hz=asked.output_rate_hz)

    def _control(self, data: bytes) -> None:
        try:
            control = dot.Control.decode(data)
        except wp.DecodeError as e:
            raise wp.GattError("invalid_value", str(e)) from e
        if control.action == 1:
            if control.payload_mode != dot.PayloadMode.RATE_QUANTITIES:
                raise wp.GattError("invalid_value", f"this simulated DOT streams Rate quantities only, not mode {control.payload_mode}")
            self.measuring = control
            self._start()
        else:
            self.measuring = dot.Control(0, control.payload_mode)
            self._end_session("measurement stopped by the central")

    def _lose_central(self) -> wp.Central:
        self.measuring = dot.Control(0, self.measuring.payload_mode)  # the DOT stops measuring when the link goes
        return super()._lose_central()

    def _send(self, s: WearableSession, j: int) -> None:
        blk = self.source.block(j, j + 1)
        assert self._central is not None
        if dot.MEDIUM_PAYLOAD_CHAR not in self._notifying:
            return
        note = dot.encode_rate_quantities(self._sample_times_us(s, j, j + 1), blk.accel[0], blk.gyro[0])
        if self._corrupt_pending > 0:
            self._corrupt_pending -= 1
            self.stats.packets_corrupted += 1
            note = note[:20]
        s.sent_any = True
        self.stats.packets_sent += 1
        self._central.notify(dot.MEDIUM_PAYLOAD_CHAR, note)
