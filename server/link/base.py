"""The wearable link's interface and the types it speaks (see docs/protocol.md, "Client API").

A link connects to one wearable, reads its configuration and device information, starts the
stream, and yields what arrives through :meth:`WearableLink.samples`: :class:`SampleBatch` objects
(decoded samples with device timestamps and an unwrapped sample counter) interleaved, in order, with
:class:`LinkEvent` objects (link lost, link restored with the size of the gap, reconnection given up,
stream ended). Two transports implement it: ``server.link.ble.BleLink`` (bleak, real BlueZ or the
simulated one) and ``server.link.inprocess.InProcessLink`` (a peripheral object in this process).
"""

from __future__ import annotations

from collections import deque
from collections.abc import AsyncIterator, Callable, Iterable
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np

from calib.errors import GyrocalError
from calib.recording import Recording, RecordingMeta
from wearable_protocol import DeviceConfig, HeldCalibration, PowerUp


class LinkError(GyrocalError):
    """The wearable link failed; the message says what happened and what to try. ``retryable``: whether
    connect() should try again (False when the transport has retried already, or retrying cannot help)."""

    retryable = True


class DeviceNotFoundError(LinkError):
    """No wearable answered the scan (switched off, out of range, or already connected elsewhere)."""


class ConnectError(LinkError):
    """The wearable was found but the connection could not be set up."""


class CommandError(LinkError):
    """The wearable refused or did not answer a control command."""


def connect_gave_up(address: str | None, attempts: int, cause: object) -> ConnectError:
    """The error after the last of ``attempts`` connection attempts failed (not to be retried again)."""
    err = ConnectError(f"could not connect to wearable {address} after {attempts} attempts ({cause}); "
                       "move it closer, check it is charged and not connected to another phone or computer")
    err.retryable = False
    return err


class WriteBackError(LinkError):
    """A calibration could not be written to the wearable, or what it reads back is not what was written."""


@dataclass(frozen=True)
class DiscoveredDevice:
    """A wearable seen in a scan; ``model``: the protocol its advertisement names (``wearable_protocol.models``)."""

    address: str
    name: str | None
    rssi: int | None = None
    model: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"address": self.address, "name": self.name, "rssi": self.rssi, "model": self.model}


def by_signal(found: Iterable[DiscoveredDevice]) -> list[DiscoveredDevice]:
    """Scan results, the strongest signal first (an unknown strength last)."""
    return sorted(found, key=lambda d: -(d.rssi if d.rssi is not None else -999))


@dataclass(frozen=True)
class DeviceInfo:
    """What the wearable says about itself: IMU configuration, Device Information, battery.

    The Device Information and Battery services are optional (some host stacks hide or lock them):
    their fields are None when absent or unreadable. ``model`` is the Device Information model number;
    ``device_model`` the protocol gyrocal speaks with it (``wearable_protocol.models``).
    """

    address: str
    name: str | None
    config: DeviceConfig
    manufacturer: str | None = None
    model: str | None = None
    serial: str | None = None
    firmware: str | None = None
    battery_pct: int | None = None
    device_model: str = "gyrocal"
    power_up: PowerUpReading | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "address": self.address, "name": self.name, "config": self.config.to_dict(),
            "manufacturer": self.manufacturer, "model": self.model, "serial": self.serial,
            "firmware": self.firmware, "battery_pct": self.battery_pct, "device_model": self.device_model,
            **(self.power_up.to_dict() if self.power_up else {"boot_count": None, "booted_at": None, "temperature_c": None}),
        }


@dataclass(frozen=True)
class PowerUpReading:
    """The device's power-up as read at ``read_at``: its boot count (None: it keeps none), when it started (the
    read time minus its uptime, to the second) and its IMU's temperature in degC (None: no sensor)."""

    boot_count: int | None
    booted_at: datetime
    temperature_c: float | None
    read_at: datetime

    @classmethod
    def from_power_up(cls, p: PowerUp, read_at: datetime) -> PowerUpReading:
        return cls(p.boot_count, (read_at - timedelta(seconds=p.uptime_s)).replace(microsecond=0), p.temperature_c, read_at)

    def to_dict(self) -> dict[str, Any]:
        return {"boot_count": self.boot_count, "booted_at": self.booted_at.isoformat(), "temperature_c": self.temperature_c}


@dataclass(frozen=True, eq=False)
class SampleBatch:
    """Consecutive samples from the wearable.

    ``t_device_s`` (n,): device time of each sample, seconds from the first sample this link received
    (unwrapped; spacing from the device-clock estimate of the true rate). ``gyro_dps`` (n, 3): raw
    readings m in deg/s. ``accel_g`` (n, 3). ``seq`` (n,): unwrapped sample counter (one step per
    sample; a jump means lost samples). ``lost_before``: samples lost between the previous batch and
    this one (0 when contiguous). ``fs_hz``: the current estimate of the true sample rate from device
    time. ``saturated`` (n,): gyro at the int16 limit on some axis. ``arrival_times``: the device sends no
    time stamps, so the times were placed from arrival times (evenly, at the rate estimated so far).
    ``fs_rel_std``: the relative standard error of ``fs_hz`` when it comes from arrival times, else None.
    ``refused_before``: samples missing before this batch because the wearable sent their packets malformed (the link
    received and refused them: its firmware's doing, not the radio's); ``lost_before`` counts the radio's only.
    """

    t_device_s: np.ndarray
    gyro_dps: np.ndarray
    accel_g: np.ndarray
    seq: np.ndarray
    lost_before: int
    fs_hz: float
    saturated: np.ndarray
    arrival_times: bool = False
    fs_rel_std: float | None = None
    refused_before: int = 0

    def __len__(self) -> int:
        return int(self.t_device_s.size)

    @staticmethod
    def concat(batches: list[SampleBatch]) -> SampleBatch:
        """One batch from consecutive ones (lost_before of the first, latest rate estimate)."""
        if len(batches) == 1:
            return batches[0]
        return SampleBatch(
            np.concatenate([b.t_device_s for b in batches]),
            np.concatenate([b.gyro_dps for b in batches]),
            np.concatenate([b.accel_g for b in batches]),
            np.concatenate([b.seq for b in batches]),
            batches[0].lost_before + sum(b.lost_before for b in batches[1:]),
            batches[-1].fs_hz,
            np.concatenate([b.saturated for b in batches]),
            any(b.arrival_times for b in batches),
            batches[-1].fs_rel_std,
            sum(b.refused_before for b in batches),
        )


LinkEventKind = Literal["link_lost", "link_restored", "link_failed", "stream_ended"]


@dataclass(frozen=True)
class LinkEvent:
    """Something that happened to the link, in stream order.

    - ``link_lost``: the connection dropped; ``t_device_s`` is the last sample received before.
    - ``link_restored``: reconnected and streaming again; ``gap_samples`` samples (``gap_s`` seconds of
      device time) were lost, ``t_device_s`` is the first sample after the gap, ``attempts`` the
      connection attempts it took, ``downtime_s`` the wall-clock time without a link. The next batch
      has ``lost_before == gap_samples``.
    - ``link_failed``: reconnection gave up (``message`` says why); the stream ends after this event.
    - ``stream_ended``: the wearable ended the stream itself (a replay finished); the stream ends.
    """

    kind: LinkEventKind
    t_device_s: float | None = None
    gap_samples: int | None = None
    gap_s: float | None = None
    attempts: int = 0
    downtime_s: float | None = None
    message: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in ("kind", "t_device_s", "gap_samples", "gap_s", "attempts", "downtime_s", "message")}


@dataclass
class LinkStats:
    """Counters of one link (cumulative over reconnections)."""

    packets: int = 0  # valid data packets decoded
    samples: int = 0
    lost_samples: int = 0  # sequence gaps x N, including link outages, less the packets the link refused
    lost_packets: int = 0
    malformed_packets: int = 0  # dropped: bad length, version, flags, N, config id, clock, sequence and time disagreeing
    malformed_reasons: dict[str, int] = field(default_factory=dict)
    duplicate_packets: int = 0  # same or older sequence number: dropped
    link_losses: int = 0
    reconnects: int = 0  # losses the link came back from (streaming again, counted with its link_restored event)
    session_restarts: int = 0  # the device started a new session mid-stream (gap from device time)
    resyncs: int = 0  # the device's clock or sequence jumped and stayed: followed after RESYNC_AFTER packets agreed
    fs_estimate_hz: float | None = None

    def refused(self, reason: str, count: int = 1) -> None:
        """Count ``count`` packets dropped for ``reason``; a negative count takes back packets that were held as
        outliers and then delivered after all (server.link.outliers)."""
        self.malformed_packets += count
        left = self.malformed_reasons.get(reason, 0) + count
        if left:
            self.malformed_reasons[reason] = left
        else:
            self.malformed_reasons.pop(reason, None)

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__, malformed_reasons=dict(self.malformed_reasons))


@dataclass(frozen=True)
class ReconnectPolicy:
    """Backoff for reconnection: delays initial, initial*factor, ... capped at max_delay, for at most
    ``timeout_s`` of wall time. ``connect_attempts``: tries of the first connect() before it fails."""

    initial_delay_s: float = 0.25
    factor: float = 2.0
    max_delay_s: float = 5.0
    timeout_s: float = 60.0
    connect_attempts: int = 3

    def delays(self) -> Iterable[float]:
        d = self.initial_delay_s
        while True:
            yield d
            d = min(self.max_delay_s, d * self.factor)


@runtime_checkable
class WearableLink(Protocol):
    """One wearable over some transport. Typical use::

        link = BleLink(address)            # or InProcessLink(peripheral)
        await link.connect()
        info = await link.read_info()
        await link.start()
        async for item in link.samples():  # SampleBatch | LinkEvent, in order
            ...
        await link.stop()
        await link.disconnect()
    """

    address: str | None
    stats: LinkStats
    last_data_mono: float | None  # when samples last arrived from the transport (time.monotonic), None before any
    clock: Callable[[], float]  # the central's clock (s) arrivals are timed on: a simulated wearable's own time scale

    async def scan(self, timeout: float = 5.0) -> list[DiscoveredDevice]:
        """Wearables advertising the IMU service, strongest first (works before connect)."""

    async def connect(self) -> None:
        """Connect (scanning for the address first); raises DeviceNotFoundError / ConnectError."""

    async def read_info(self) -> DeviceInfo:
        """Read the IMU configuration and the optional device information and battery level."""

    async def read_power_up(self) -> PowerUpReading | None:
        """Boot count, power-up time and temperature now (None: the device reports none)."""

    async def configure(self, *, sample_rate_hz: float | None = None, gyro_full_scale_dps: int | None = None,
                        accel_range_g: int | None = None) -> DeviceConfig:
        """Change settings (not while streaming); returns the new configuration. Raises CommandError."""

    async def start(self) -> None:
        """Start streaming (resumes the device's session if one is active)."""

    async def stop(self) -> None:
        """Stop streaming and end the device's session; samples() then ends."""

    async def disconnect(self) -> None:
        """Disconnect on purpose (no reconnection); samples() ends."""

    @property
    def holds_calibrations(self) -> bool:
        """Whether the connected wearable can hold a calibration written to it."""

    async def held_calibration(self) -> HeldCalibration | None:
        """The calibration the wearable says it holds (None: none); WriteBackError if it cannot hold one."""

    async def write_calibration(self, held: HeldCalibration) -> HeldCalibration:
        """Write a calibration, read it back and verify it; WriteBackError when the device refuses or differs."""

    async def identify(self, seconds: int) -> None:
        """Make the wearable blink or buzz for ``seconds``; CommandError when its protocol has no such command."""

    def samples(self) -> AsyncIterator[SampleBatch | LinkEvent]:
        """The stream, in order. Ends after stop(), disconnect(), link_failed or stream_ended."""


class RecordingBuilder:
    """Collects SampleBatches into a :class:`calib.Recording` (t = device time, seq = sample counter)."""

    def __init__(self, info: DeviceInfo | None = None, source: str | None = None) -> None:
        self.info = info
        self.source = source
        self._batches: list[SampleBatch] = []
        self.lost_samples = 0

    def add(self, batch: SampleBatch) -> None:
        if self._batches:
            self.lost_samples += batch.lost_before + batch.refused_before
        self._batches.append(batch)

    def __len__(self) -> int:
        return sum(len(b) for b in self._batches)

    def recording(self) -> Recording:
        """The samples so far; the rate is the device-time estimate of the last batch. Samples timed by arrival
        are re-timed from the sample counter at the final rate estimate."""
        if not self._batches:
            raise LinkError("no samples were received from the wearable")
        b = SampleBatch.concat(self._batches)
        cfg = self.info.config if self.info else None
        meta = RecordingMeta(
            sample_rate_hz=b.fs_hz,
            device_id=(self.info.serial or self.info.address) if self.info else None,
            sensor_model=self.info.model if self.info else None,
            gyro_full_scale_dps=float(cfg.gyro_full_scale_dps) if cfg else None,
            source=self.source or (f"wearable {self.info.address}" if self.info else "wearable"),
        )
        rec = Recording(b.t_device_s, b.gyro_dps, b.accel_g, b.seq, None, meta)
        return rec.timed_by_counter(b.fs_hz, b.fs_rel_std) if b.arrival_times else rec


def merge_queued(first: SampleBatch, queue: deque[object], most: int) -> SampleBatch:
    """``first`` and the batches queued after it that follow it without a gap (at most ``most`` in all), taken off
    ``queue`` and merged into one: a consumer that fell behind gets them at once."""
    merged = [first]
    while queue and len(merged) < most:
        nxt = queue[0]
        if not isinstance(nxt, SampleBatch) or nxt.lost_before or nxt.refused_before:
            break
        merged.append(nxt)
        queue.popleft()
    return SampleBatch.concat(merged)
