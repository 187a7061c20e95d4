"""What a protocol adapter is: one wearable model's GATT exchange turned into gyrocal's sample stream.

The link (``server.link.core.LinkCore``) owns the connection, reconnection and the stream of batches and
events; an adapter owns what differs between models: which characteristics to subscribe, how to
configure, start and stop, and how the data notifications decode into :class:`SampleBatch` objects
(deg/s, g, device or arrival times, the sample counter and the samples lost before each batch).
"""

from __future__ import annotations

import asyncio
import logging
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Hashable
from typing import Any, ClassVar, Protocol

import wearable_protocol as wp
from wearable_protocol import DeviceConfig, DeviceState, HeldCalibration, PowerUp
from wearable_protocol.models import CANNOT_HOLD, CANNOT_IDENTIFY, DeviceModel

from ..base import CommandError, LinkError, LinkStats, SampleBatch, WriteBackError

log = logging.getLogger(__name__)


class GattIO(Protocol):
    """The GATT operations of the connected device, as the link's transport offers them."""

    def has(self, char_uuid: str) -> bool: ...

    async def read(self, char_uuid: str) -> bytes: ...

    async def write(self, char_uuid: str, data: bytes, *, response: bool = True) -> None: ...

    async def subscribe(self, char_uuid: str, callback: Callable[[bytes], None]) -> None: ...

    async def unsubscribe(self, char_uuid: str) -> None: ...


class StreamSink(Protocol):
    """Where an adapter delivers what it decoded (the link's feed)."""

    def batch(self, batch: SampleBatch) -> None: ...

    def ended(self, message: str) -> None:
        """The device ended the stream by itself."""


class Adapter(ABC):
    """One model's protocol on a connected device. ``io``: its GATT; ``sink``: where batches go;
    ``clock``: the central's clock in seconds (arrival times of devices that send none of their own)."""

    model: ClassVar[DeviceModel]
    data_char: ClassVar[str]  # the characteristic whose presence identifies the model after connecting

    def __init__(self, io: GattIO, stats: LinkStats, sink: StreamSink, *, command_timeout_s: float = 5.0,
                 clock: Callable[[], float] | None = None) -> None:
        self.io = io
        self.stats = stats
        self.sink = sink
        self.command_timeout_s = command_timeout_s
        self.clock = clock or time.monotonic
        self.config: DeviceConfig | None = None
        self.last_t_s: float | None = None  # time of the last sample delivered
        self._waiters: dict[Hashable, asyncio.Future[Any]] = {}
        self._setup()

    def _setup(self) -> None:  # noqa: B027 - optional hook for a subclass's own state
        """A subclass's own state."""

    @classmethod
    def recognises(cls, io: GattIO) -> bool:
        return io.has(cls.data_char)

    @abstractmethod
    async def open(self) -> DeviceConfig:
        """After connecting: subscribe to what replies, read or negotiate the configuration."""

    async def read_config(self) -> DeviceConfig:
        """The configuration now (read again where the device has it to read)."""
        assert self.config is not None
        return self.config

    @abstractmethod
    async def configure(self, *, sample_rate_hz: float | None, gyro_full_scale_dps: int | None,
                        accel_range_g: int | None) -> DeviceConfig:
        """Change the settings the next start uses; CommandError when the device does not offer them."""

    @abstractmethod
    async def start(self, *, resume: bool) -> None:
        """Subscribe to the data and start streaming; ``resume``: after a reconnection."""

    @abstractmethod
    async def stop(self) -> None:
        """Stop streaming and unsubscribe from the data."""

    async def details(self) -> dict[str, Any]:
        """What the device says about itself: manufacturer, model, serial, firmware (the Device Information service)
        and battery_pct (the Battery service). Both are optional (some host stacks hide or lock them): a field absent
        or unreadable is left out. A protocol with characteristics of its own for these reads those instead."""
        out: dict[str, Any] = {}
        for key, uuid in (("manufacturer", wp.MANUFACTURER_NAME_CHAR), ("model", wp.MODEL_NUMBER_CHAR),
                          ("serial", wp.SERIAL_NUMBER_CHAR), ("firmware", wp.FIRMWARE_REVISION_CHAR),
                          ("battery_pct", wp.BATTERY_LEVEL_CHAR)):
            raw = await self._optional(uuid)
            if raw:
                out[key] = raw[0] if key == "battery_pct" else raw.decode("utf-8", "replace").rstrip("\x00")
        return out

    async def _optional(self, uuid: str) -> bytes | None:
        if not self.io.has(uuid):
            return None
        try:
            return await self.io.read(uuid)
        except Exception as e:  # locked or hidden by the host stack: the field is simply unknown
            log.info("optional characteristic %s not readable: %s", uuid, e)
            return None

    async def power_up(self) -> PowerUp | None:
        """The device's boot count, uptime and temperature; None when its protocol reports none (no vendor's does)."""
        return None

    @property
    def holds_calibrations(self) -> bool:
        """Whether this device can hold a calibration written to it (no vendor protocol offers it)."""
        return False

    async def held_calibration(self) -> HeldCalibration | None:
        """What the device says it holds."""
        raise WriteBackError(f"a {self.model.label} {CANNOT_HOLD}")

    async def write_calibration(self, held: HeldCalibration) -> None:
        """Send a calibration to the device (the link reads it back)."""
        raise WriteBackError(f"a {self.model.label} {CANNOT_HOLD}")

    async def identify(self, seconds: int) -> None:
        """Make the device blink or buzz for ``seconds`` so the clinician can tell it from the others (streaming goes
        on); CommandError when its protocol has no such command (``model.identify`` is None)."""
        raise CommandError(f"a {self.model.label} {CANNOT_IDENTIFY}")

    async def _exchange(self, key: Hashable, char_uuid: str, data: bytes, what: str) -> Any:
        """Write a command and wait for the reply that ``_answer(key, reply)`` delivers; CommandError when the
        device does not answer in time or the write fails, LinkError when the link drops meanwhile."""
        fut: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        self._waiters[key] = fut
        try:
            await self.io.write(char_uuid, data)
            return await asyncio.wait_for(fut, self.command_timeout_s)
        except TimeoutError:
            raise CommandError(f"the {self.model.label} did not answer {what} within {self.command_timeout_s:g} s") from None
        except LinkError:
            raise
        except Exception as e:
            raise CommandError(f"{what} could not be sent: {e}") from e
        finally:
            self._waiters.pop(key, None)

    def _answer(self, key: Hashable, reply: Any) -> None:
        fut = self._waiters.get(key)
        if fut is not None and not fut.done():
            fut.set_result(reply)

    def link_lost(self) -> None:
        """The connection dropped: fail whatever waits for the device's answer."""
        for fut in self._waiters.values():
            if not fut.done():
                fut.set_exception(LinkError("the link dropped while waiting for the wearable's answer"))


def fixed_range_rate(model: DeviceModel, name: str, streams: str, sample_rate_hz: float | None, gyro_full_scale_dps: int | None,
                     accel_range_g: int | None) -> int | None:
    """The rate asked of a device whose ranges are fixed (the model's only ones): the whole rate when it offers it, None
    when none was asked; CommandError naming what it offers otherwise. ``streams``: how its rate is said ("streams")."""
    if gyro_full_scale_dps not in (None, model.gyro_range_dps):
        raise CommandError(f"the {name}'s gyro range is fixed at {model.gyro_range_dps} deg/s")
    if accel_range_g not in (None, model.accel_range_g):
        raise CommandError(f"the {name}'s accelerometer range is fixed at {model.accel_range_g} g")
    if sample_rate_hz is None:
        return None
    if not model.offers_rate(float(sample_rate_hz)):
        raise CommandError(f"the {name} {streams} at {model.rates_text()}; {sample_rate_hz:g} Hz is not one")
    return int(sample_rate_hz)


def vendor_config(rate_hz: float, gyro_dps: int, accel_g: int, samples_per_packet: int,
                 gyro_lsb_per_dps: float, accel_lsb_per_g: float, streaming: bool = False) -> DeviceConfig:
    """The configuration of a vendor device in gyrocal's terms (config id 0: vendors number none)."""
    return DeviceConfig(0, float(rate_hz), int(gyro_dps), int(accel_g), int(samples_per_packet), float(gyro_lsb_per_dps),
                        float(accel_lsb_per_g), DeviceState.STREAMING if streaming else DeviceState(0))
