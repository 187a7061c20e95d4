"""gyrocal's own protocol (docs/protocol.md): commands with status replies, the config characteristic,
packets with a sequence number and the device clock."""

from __future__ import annotations

import logging

import wearable_protocol as wp
from wearable_protocol import (
    Command,
    DecodeError,
    DeviceConfig,
    DeviceState,
    HeldCalibration,
    Opcode,
    Status,
    StatusReply,
    decode_slot,
)
from wearable_protocol.models import GYROCAL

from ..base import CommandError, ConnectError, WriteBackError
from ..decoder import StreamDecoder
from .base import Adapter

log = logging.getLogger(__name__)


class GyrocalAdapter(Adapter):
    """A wearable speaking gyrocal's protocol."""

    model = GYROCAL
    data_char = wp.IMU_DATA_CHAR

    _decoder: StreamDecoder | None = None

    async def open(self) -> DeviceConfig:
        await self.io.subscribe(wp.IMU_CONTROL_CHAR, self._on_control)
        cfg = await self.read_config()
        if self._decoder is None:
            self._decoder = StreamDecoder(cfg, self.stats)
        return cfg

    async def read_config(self) -> DeviceConfig:
        if not self.io.has(wp.IMU_CONFIG_CHAR) or not self.io.has(wp.IMU_DATA_CHAR):
            raise ConnectError("the device does not offer the gyrocal IMU service; is it a gyrocal wearable?")
        try:
            cfg = DeviceConfig.decode(await self.io.read(wp.IMU_CONFIG_CHAR))
        except DecodeError as e:
            raise ConnectError(f"the wearable sent an unreadable configuration ({e}); update its firmware") from e
        self.config = cfg
        if self._decoder is not None:
            self._decoder.set_config(cfg)
        return cfg

    async def _command(self, cmd: Command) -> StatusReply:
        reply: StatusReply = await self._exchange(int(cmd.opcode), wp.IMU_CONTROL_CHAR, cmd.encode(), cmd.opcode.name)
        if reply.status != Status.OK:
            hint = {Status.BUSY: "stop streaming first", Status.INVALID_VALUE: "use a supported value",
                    Status.NOT_SUPPORTED: "this device has fixed settings",
                    Status.CHECKSUM: "the bytes were damaged on the way; write again",
                    Status.UNKNOWN_OPCODE: "its firmware is older than this command"}.get(reply.status, "")
            raise CommandError(f"the wearable refused {cmd.opcode.name}: {reply.status.name.lower()}"
                               + (f" ({hint})" if hint else ""))
        return reply

    async def configure(self, *, sample_rate_hz: float | None, gyro_full_scale_dps: int | None,
                        accel_range_g: int | None) -> DeviceConfig:
        if sample_rate_hz is not None:
            await self._command(Command(Opcode.SET_RATE, float(sample_rate_hz)))
        if gyro_full_scale_dps is not None:
            await self._command(Command(Opcode.SET_GYRO_RANGE, int(gyro_full_scale_dps)))
        if accel_range_g is not None:
            await self._command(Command(Opcode.SET_ACCEL_RANGE, int(accel_range_g)))
        cfg = await self.read_config()
        self._decoder = StreamDecoder(cfg, self.stats)
        return cfg

    async def power_up(self) -> wp.PowerUp | None:
        if not self.io.has(wp.IMU_POWER_UP_CHAR):  # firmware older than the power-up characteristic
            return None
        try:
            return wp.PowerUp.decode(await self.io.read(wp.IMU_POWER_UP_CHAR))
        except DecodeError as e:
            log.warning("the wearable's power-up characteristic is unreadable (%s): its power-up stays unknown", e)
            return None

    @property
    def holds_calibrations(self) -> bool:
        return self.io.has(wp.IMU_CALIBRATION_CHAR)

    async def held_calibration(self) -> HeldCalibration | None:
        if not self.holds_calibrations:
            return await super().held_calibration()
        try:
            return decode_slot(await self.io.read(wp.IMU_CALIBRATION_CHAR))
        except DecodeError as e:
            raise WriteBackError(f"the wearable's held calibration is unreadable ({e})") from e

    async def write_calibration(self, held: HeldCalibration) -> None:
        if not self.holds_calibrations:
            await super().write_calibration(held)
        try:
            await self._command(Command(Opcode.WRITE_CALIBRATION, held.payload()))
        except CommandError as e:
            raise WriteBackError(str(e)) from e

    async def identify(self, seconds: int) -> None:
        await self._command(Command(Opcode.IDENTIFY, int(seconds)))

    async def start(self, *, resume: bool) -> None:
        cfg = self.config
        assert cfg is not None and self._decoder is not None
        await self.io.subscribe(wp.IMU_DATA_CHAR, self._on_data)
        self._decoder.begin(new_session=not cfg.state & DeviceState.SESSION_ACTIVE)
        await self._command(Command(Opcode.START))

    async def stop(self) -> None:
        await self._command(Command(Opcode.STOP))
        await self.io.unsubscribe(wp.IMU_DATA_CHAR)

    def _on_data(self, data: bytes) -> None:
        if self._decoder is None:
            return
        batch = self._decoder.feed(data)
        if batch is not None:
            self.last_t_s = self._decoder.last_t_s
            self.sink.batch(batch)

    def _on_control(self, data: bytes) -> None:
        try:
            reply = StatusReply.decode(data)
        except DecodeError as e:
            log.warning("unreadable control reply %r: %s", bytes(data), e)
            return
        if reply.opcode == Opcode.STREAM_END:
            self.sink.ended("the wearable ended the stream")
            return
        self._answer(reply.opcode, reply)
