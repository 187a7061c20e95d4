"""What a protocol adapter is: one wearable model's GATT exchange turned into gyrocal's sample stream.

The link (``server.link.core.LinkCore``) owns the connection, reconnection and the stream of batches and
events; an adapter owns what differs between models: which characteristics to subscribe, how to
configure, start and stop, and how the data notifications decode into :class:`SampleBatch` objects
(deg/s, g, device or arrival times, the sample counter and the samples lost before each batch).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import ClassVar, Protocol

from wearable_protocol import DeviceConfig, DeviceState
from wearable_protocol.models import DeviceModel

from ..base import LinkStats, SampleBatch

MIN_SPAN_FOR_RATE_S = 0.5  # below this span of time the nominal rate is used


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


class RateFit:
    """Running least-squares fit t = a + counter / fs over (counter, t_us) pairs, centred for accuracy."""

    def __init__(self) -> None:
        self.n = 0
        self.x0 = 0
        self.y0 = 0
        self.sx = self.sy = self.sxx = self.sxy = 0.0
        self.span_us = 0

    def add(self, counter: int, t_us: int) -> None:
        if self.n == 0:
            self.x0, self.y0 = counter, t_us
        x = float(counter - self.x0)
        y = float(t_us - self.y0)
        self.n += 1
        self.sx += x
        self.sy += y
        self.sxx += x * x
        self.sxy += x * y
        self.span_us = max(self.span_us, t_us - self.y0)

    def rate(self, nominal: float) -> float:
        if self.n < 3 or self.span_us < MIN_SPAN_FOR_RATE_S * 1e6:
            return nominal
        var = self.sxx - self.sx * self.sx / self.n
        cov = self.sxy - self.sx * self.sy / self.n
        if var <= 0 or cov <= 0:
            return nominal
        return 1e6 * var / cov


class Adapter(ABC):
    """One model's protocol on a connected device. ``io``: its GATT; ``sink``: where batches go;
    ``clock``: the central's clock in seconds (arrival times of devices that send none of their own)."""

    model: ClassVar[DeviceModel]
    data_char: ClassVar[str]  # the characteristic whose presence identifies the model after connecting

    def __init__(self, io: GattIO, stats: LinkStats, sink: StreamSink, *, command_timeout_s: float = 5.0,
                 clock: Callable[[], float] | None = None) -> None:
        import time

        self.io = io
        self.stats = stats
        self.sink = sink
        self.command_timeout_s = command_timeout_s
        self.clock = clock or time.monotonic
        self.config: DeviceConfig | None = None
        self.last_t_s: float | None = None  # time of the last sample delivered
        self._setup()

    def _setup(self) -> None:  # noqa: B027 - optional hook
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

    def link_lost(self) -> None:  # noqa: B027 - optional hook
        """The connection dropped: fail whatever waits for the device's answer."""


def vendor_config(rate_hz: float, gyro_dps: int, accel_g: int, samples_per_packet: int,
                 gyro_lsb_per_dps: float, accel_lsb_per_g: float, streaming: bool = False) -> DeviceConfig:
    """The configuration of a vendor device in gyrocal's terms (config id 0: vendors number none)."""
    return DeviceConfig(0, float(rate_hz), int(gyro_dps), int(accel_g), int(samples_per_packet), float(gyro_lsb_per_dps),
                        float(accel_lsb_per_g), DeviceState.STREAMING if streaming else DeviceState(0))
