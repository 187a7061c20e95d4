"""What both transports share: the protocol adapter of the connected model, the decoded stream with its
events, and reconnection with backoff after a link loss. A transport supplies the GATT primitives (``_t_*``)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import AsyncIterator, Callable
from datetime import UTC, datetime

from wearable_protocol import DeviceConfig, HeldCalibration
from wearable_protocol.models import DeviceModel

from .adapters import ADAPTERS, Adapter, recognise
from .base import (
    CommandError,
    ConnectError,
    DeviceInfo,
    DeviceNotFoundError,
    DiscoveredDevice,
    LinkError,
    LinkEvent,
    LinkStats,
    PowerUpReading,
    ReconnectPolicy,
    SampleBatch,
    WriteBackError,
    connect_gave_up,
    merge_queued,
)

log = logging.getLogger(__name__)

_END = object()  # ends one samples() iteration
MAX_MERGE = 64  # at most this many queued batches are merged into one when the consumer lags


class _LinkIO:
    """The transport's GATT primitives under the names adapters use."""

    def __init__(self, core: LinkCore) -> None:
        self.core = core

    def has(self, char_uuid: str) -> bool:
        return self.core._t_has(char_uuid)

    async def read(self, char_uuid: str) -> bytes:
        return await self.core._t_read(char_uuid)

    async def write(self, char_uuid: str, data: bytes, *, response: bool = True) -> None:
        await self.core._t_write(char_uuid, data, response=response)

    async def subscribe(self, char_uuid: str, callback: Callable[[bytes], None]) -> None:
        await self.core._t_subscribe(char_uuid, callback)

    async def unsubscribe(self, char_uuid: str) -> None:
        await self.core._t_unsubscribe(char_uuid)


class _Sink:
    def __init__(self, core: LinkCore) -> None:
        self.core = core

    def batch(self, batch: SampleBatch) -> None:
        self.core._on_batch(batch)

    def ended(self, message: str) -> None:
        self.core._on_stream_end(message)


class LinkCore(ABC):
    """Shared behaviour of :class:`~server.link.base.WearableLink` transports.

    ``model``: the wearable model's key (``wearable_protocol.models``); None: recognised from the
    characteristics the device offers once connected. ``clock``: the central's clock (s), for the arrival
    times of models that send no time stamps.
    """

    def __init__(self, address: str | None, *, reconnect: ReconnectPolicy | None = None,
                 command_timeout_s: float = 5.0, model: str | None = None,
                 clock: Callable[[], float] | None = None) -> None:
        if model is not None and model not in ADAPTERS:
            raise LinkError(f"unknown wearable model {model!r}: choose one of {', '.join(ADAPTERS)}")
        self.address = address
        self.name: str | None = None
        self.model_key = model
        self.policy = reconnect or ReconnectPolicy()
        self.command_timeout_s = command_timeout_s
        self.clock = clock or time.monotonic
        self.stats = LinkStats()
        self.protocol: Adapter | None = None
        self._feed: deque[object] = deque()
        self._feed_ready = asyncio.Event()
        self._connected = False
        self._streaming = False  # the central wants the stream (survives link loss)
        self._closing = False
        self._reconnect_task: asyncio.Task[None] | None = None
        self._restore: tuple[int, float] | None = None  # (attempts, time of loss) until the first batch after
        self.last_data_mono: float | None = None  # when the transport last handed over samples (time.monotonic)

    @property
    def config(self) -> DeviceConfig | None:
        """The device's configuration as last read or negotiated (None before the first connection)."""
        return self.protocol.config if self.protocol is not None else None

    @property
    def model(self) -> DeviceModel | None:
        """The connected (or named) model; None before connecting to an unnamed one."""
        key = self.protocol.model.key if self.protocol is not None else self.model_key
        return ADAPTERS[key].model if key else None

    # ------------------------------------------------------------------ transport primitives

    @abstractmethod
    async def scan(self, timeout: float = 5.0) -> list[DiscoveredDevice]: ...

    @abstractmethod
    async def _t_connect(self) -> None:
        """Open the connection; raise DeviceNotFoundError or ConnectError."""

    @abstractmethod
    async def _t_disconnect(self) -> None: ...

    @abstractmethod
    def _t_has(self, char_uuid: str) -> bool:
        """Whether the connected device exposes this characteristic."""

    @abstractmethod
    async def _t_read(self, char_uuid: str) -> bytes: ...

    @abstractmethod
    async def _t_write(self, char_uuid: str, data: bytes, *, response: bool = True) -> None: ...

    @abstractmethod
    async def _t_subscribe(self, char_uuid: str, callback: Callable[[bytes], None]) -> None: ...

    @abstractmethod
    async def _t_unsubscribe(self, char_uuid: str) -> None: ...

    # ------------------------------------------------------------------ public API

    @property
    def connected(self) -> bool:
        return self._connected

    async def connect(self) -> None:
        """Connect, subscribe to control replies and read the configuration.

        Retries transient failures (the link dropping during setup) ``policy.connect_attempts`` times
        with backoff; raises DeviceNotFoundError at once when no device answers the scan.
        """
        self._closing = False
        delays = iter(self.policy.delays())
        for attempt in range(1, self.policy.connect_attempts + 1):
            try:
                await self._open()
                return
            except DeviceNotFoundError:
                raise
            except LinkError as e:
                if not e.retryable:
                    raise
                if attempt == self.policy.connect_attempts:
                    raise connect_gave_up(self.address, attempt, e) from e
                log.info("connect attempt %d failed (%s), retrying", attempt, e)
                await asyncio.sleep(next(delays))

    async def _open(self) -> None:
        await self._t_connect()
        try:
            adapter = self.protocol
            if adapter is None:
                io = _LinkIO(self)
                cls = ADAPTERS[self.model_key] if self.model_key else recognise(io)
                if cls is None:
                    raise ConnectError(f"{self.address} offers none of the protocols gyrocal speaks ("
                                       + ", ".join(ADAPTERS) + "); is it a supported wearable?")
                adapter = cls(io, self.stats, _Sink(self), command_timeout_s=self.command_timeout_s, clock=self.clock)
            await adapter.open()
            self.protocol = adapter
        except Exception as e:
            with contextlib.suppress(Exception):
                await self._t_disconnect()
            if isinstance(e, LinkError):
                raise
            raise ConnectError(f"connection to {self.address} failed during setup: {e}") from e  # a transport error
        self._connected = True

    def _require(self) -> Adapter:
        if not self._connected or self.protocol is None:
            raise LinkError("the wearable is not connected: call connect() first")
        return self.protocol

    def _last_t(self) -> float | None:
        return self.protocol.last_t_s if self.protocol is not None else None

    async def read_info(self) -> DeviceInfo:
        """Read config, what the device says about itself (Device Information, battery: optional) and its power-up."""
        adapter = self._require()
        config = await adapter.read_config()
        d = await adapter.details()
        return DeviceInfo(self.address or "", self.name, config, d.get("manufacturer"), d.get("model"), d.get("serial"),
                          d.get("firmware"), d.get("battery_pct"), adapter.model.key, await self.read_power_up())

    async def read_power_up(self) -> PowerUpReading | None:
        """The wearable's power-up and temperature now; None when its protocol reports none or the read failed."""
        try:
            found = await self._require().power_up()
        except Exception as e:  # a lost link or a refused read: the power-up is simply unknown this time
            log.info("power-up not readable: %s", e)
            return None
        return None if found is None else PowerUpReading.from_power_up(found, datetime.now(UTC))

    async def configure(self, *, sample_rate_hz: float | None = None, gyro_full_scale_dps: int | None = None,
                        accel_range_g: int | None = None) -> DeviceConfig:
        """Change rate and ranges (refused while streaming); returns the configuration read back."""
        if self._streaming:
            raise CommandError("cannot change the configuration while streaming: stop() first")
        return await self._require().configure(sample_rate_hz=sample_rate_hz, gyro_full_scale_dps=gyro_full_scale_dps,
                                               accel_range_g=accel_range_g)

    @property
    def holds_calibrations(self) -> bool:
        """Whether the connected wearable can hold a calibration written to it."""
        return self._connected and self.protocol is not None and self.protocol.holds_calibrations

    async def held_calibration(self) -> HeldCalibration | None:
        """The calibration the wearable says it holds (None: none); WriteBackError if it cannot hold one."""
        return await self._require().held_calibration()

    async def write_calibration(self, held: HeldCalibration) -> HeldCalibration:
        """Write a calibration, then read back what the device holds and compare it bit for bit (float32, CRC-32
        checked on both ways); WriteBackError when the device refuses it or holds something else."""
        adapter = self._require()
        await adapter.write_calibration(held)
        back = await adapter.held_calibration()
        if back != held:
            got = "nothing" if back is None else f"calibration {back.calibration_id} with other values"
            raise WriteBackError(f"the wearable accepted calibration {held.calibration_id} but reads back {got}; "
                                 "write it again, and if that fails, update the wearable's firmware")
        return back

    async def identify(self, seconds: int) -> None:
        """Make the wearable blink or buzz for ``seconds`` (1-60), streaming or not; CommandError if it cannot."""
        await self._require().identify(seconds)

    async def start(self) -> None:
        """Subscribe to data and start (or resume) the device's session. Items of an earlier stream that
        were never consumed are discarded."""
        adapter = self._require()
        self._feed.clear()
        await adapter.start(resume=False)
        self._streaming = True

    async def stop(self) -> None:
        """Stop streaming (the device ends its session) and end samples()."""
        was = self._streaming
        self._streaming = False
        if self._reconnect_task is not None:
            self._reconnect_task.cancel()
            self._reconnect_task = None
        if self._connected and self.protocol is not None:
            try:
                await self.protocol.stop()
            except LinkError:
                if self._connected:
                    raise
        if was:
            self._push(_END)

    async def disconnect(self) -> None:
        """Disconnect on purpose; no reconnection. samples() ends."""
        self._closing = True
        self._streaming = False
        if self._reconnect_task is not None:
            self._reconnect_task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._reconnect_task
            self._reconnect_task = None
        if self._connected:
            self._connected = False
            with contextlib.suppress(Exception):
                await self._t_disconnect()
        self._push(_END)

    async def samples(self) -> AsyncIterator[SampleBatch | LinkEvent]:
        """Batches and events in stream order; consecutive batches without a gap are merged when the
        consumer falls behind. Ends after stop(), disconnect(), link_failed or stream_ended."""
        while True:
            while not self._feed:
                self._feed_ready.clear()
                await self._feed_ready.wait()
            item = self._feed.popleft()
            if item is _END:
                return
            if isinstance(item, SampleBatch):
                yield merge_queued(item, self._feed, MAX_MERGE)
            else:
                assert isinstance(item, LinkEvent)
                yield item

    # ------------------------------------------------------------------ callbacks

    def _push(self, item: object) -> None:
        self._feed.append(item)
        self._feed_ready.set()

    def _on_batch(self, batch: SampleBatch) -> None:
        self.last_data_mono = time.monotonic()
        if self._restore is not None:
            attempts, lost_at = self._restore
            self._restore = None
            self.stats.reconnects += 1  # counted with the event that says so, not after start() returns: data may come first
            gap_s = batch.lost_before / batch.fs_hz if batch.fs_hz else None
            self._push(LinkEvent("link_restored", float(batch.t_device_s[0]), batch.lost_before, gap_s,
                                 attempts, time.monotonic() - lost_at))
        self._push(batch)

    def _on_stream_end(self, message: str) -> None:
        self._streaming = False
        self._push(LinkEvent("stream_ended", self._last_t(), message=message))
        self._push(_END)

    def _on_link_lost(self) -> None:
        """Called by the transport when the connection dropped without our asking."""
        if self._closing or not self._connected:
            return
        self._connected = False
        if self.protocol is not None:
            self.protocol.link_lost()
        if self._reconnect_task is not None and not self._reconnect_task.done():
            return  # dropped again while reconnecting: the running attempt loop carries on
        self.stats.link_losses += 1
        last = self._last_t()
        self._push(LinkEvent("link_lost", last, message="the radio link to the wearable dropped"))
        self._reconnect_task = asyncio.get_running_loop().create_task(self._reconnect(time.monotonic()))

    async def _reconnect(self, lost_at: float) -> None:
        attempts = 0
        last_error: Exception | None = None
        for delay in self.policy.delays():
            if self._closing:
                return
            remaining = self.policy.timeout_s - (time.monotonic() - lost_at)
            if remaining <= 0:
                break
            await asyncio.sleep(min(delay, remaining))
            attempts += 1
            try:
                await self._t_disconnect()  # release what is left of the old connection
            except Exception:
                pass
            try:
                await self._open()
                if self._streaming:
                    assert self.protocol is not None
                    self._restore = (attempts, lost_at)
                    await self.protocol.start(resume=True)
                else:
                    self.stats.reconnects += 1
                log.info("reconnected to %s after %d attempts", self.address, attempts)
                return
            except asyncio.CancelledError:
                raise
            except Exception as e:
                last_error = e
                self._connected = False
                log.info("reconnection attempt %d failed: %s", attempts, e)
        if not self._closing:
            self._push(LinkEvent(
                "link_failed", self._last_t(), attempts=attempts,
                downtime_s=time.monotonic() - lost_at,
                message=f"the wearable did not come back within {self.policy.timeout_s:g} s ({attempts} attempts; "
                        f"last error: {last_error})",
            ))
            self._push(_END)
            self._streaming = False
