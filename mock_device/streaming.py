"""A simulated wearable's stream as it goes out: each session's state, the packets' times on the device clock, the
packets the radio loses, the pacing of the packets against the wall clock, and the end of a stream."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

import wearable_protocol as wp
from wearable_protocol import Opcode, PacketFlags, Status, StatusReply

from .device_stats import DeviceStats
from .scenarios import LinkFaults
from .sources import SampleSource

MIN_SLEEP_S = 0.001
# A BLE link delivers notifications at connection events, not one by one: Linux asks for a connection interval of
# 30-50 ms (the kernel's le_conn_min_interval 0x0018 and le_conn_max_interval 0x0028, in 1.25 ms units), so a wearable
# streaming 37.5 packets a second sends them in pairs. The simulated one sends every packet due at each event.
CONNECTION_INTERVAL_S = 0.05

log = logging.getLogger(__name__)


@dataclass
class WearableSession:
    number: int
    fs: float  # true output data rate
    n: int
    wall0: float
    clock0_us: int  # device clock (unwrapped) at sample 0
    config_id: int
    streaming: bool = True
    next_packet: int = 0
    sent_any: bool = False
    resumed: bool = False
    drop_done: bool = False
    disconnected_wall: float | None = None
    lost_at: int = 0  # first sample not delivered when the link was lost


class Streaming:
    """How ``Wearable`` streams its sessions (the attributes are its own)."""

    source: SampleSource
    seed: int
    speed: float
    faults: LinkFaults
    config_id: int
    gyro_full_scale_dps: int
    accel_range_g: int
    data_char: str
    stats: DeviceStats
    events: list[tuple[float, str]]
    _central: Any
    _clock_start_us: int
    _corrupt_pending: int
    firmware_fault: Callable[[int, bytes], list[bytes]] | None
    connection_interval_s: float  # device time between the link's connection events (0: every packet on its own)
    _loss_cache: dict[int, np.ndarray]
    _notifying: set[str]
    _session: WearableSession | None
    _task: asyncio.Task[None] | None

    # ------------------------------------------------------------------ streaming

    def _packet_end_s(self, s: WearableSession, j: int) -> float:
        """Session time (s) at which packet j is complete."""
        last = (j + 1) * s.n - 1
        t = self.source.times_s(last, last + 1)
        return float(t[0]) if t is not None else last / s.fs

    def _sample_times_us(self, s: WearableSession, start: int, end: int) -> int:
        t = self.source.times_s(start, start + 1)
        offset = float(t[0]) if t is not None else start / s.fs
        return s.clock0_us + int(round(offset * 1e6))

    def _lost_by_radio(self, j: int) -> bool:
        p = self.faults.packet_loss
        if p <= 0:
            return False
        block, off = divmod(j, 4096)
        if block not in self._loss_cache:
            self._loss_cache[block] = np.random.default_rng([self.seed, 0x1055, block]).random(4096) < p
        return bool(self._loss_cache[block][off])

    async def _run(self, s: WearableSession) -> None:
        total = None if self.source.length is None else self.source.length // s.n
        try:
            while self._session is s:
                elapsed = (time.monotonic() - s.wall0) * self.speed
                self._advance(s, elapsed, total)
                if total is not None and s.next_packet >= total:
                    self._stream_end(s)
                    return
                due_s = self._packet_end_s(s, s.next_packet)
                if self.connection_interval_s > 0:  # the connection event the packet goes out in
                    due_s = math.ceil(due_s / self.connection_interval_s - 1e-9) * self.connection_interval_s
                wait = (s.wall0 + due_s / self.speed) - time.monotonic()
                await asyncio.sleep(max(MIN_SLEEP_S, wait))
        except asyncio.CancelledError:
            pass
        except Exception:  # the simulation behind the stream failed: said, never a stream that stops without a word
            log.exception("simulated wearable: its stream of session %d failed", s.number)
            self._end_session("its simulation failed")

    def _advance(self, s: WearableSession, elapsed: float, total: int | None) -> None:
        while self._session is s and (total is None or s.next_packet < total):
            j = s.next_packet
            if self._packet_end_s(s, j) > elapsed:
                return
            start_s = j * s.n / s.fs
            if self.faults.drop_at_s is not None and not s.drop_done and start_s >= self.faults.drop_at_s:
                s.drop_done = True
                self.drop_link()
            if self._central is None or not s.streaming or self.data_char not in self._notifying:
                self.stats.packets_lost_link += 1
            elif self._lost_by_radio(j):
                self.stats.packets_lost_radio += 1
                self.stats.lost_radio_seqs.append(j)
            else:
                self._send(s, j)
            s.next_packet = j + 1

    def _send(self, s: WearableSession, j: int) -> None:
        i0, i1 = j * s.n, (j + 1) * s.n
        blk = self.source.block(i0, i1)
        counts, clipped = wp.quantize(blk.gyro, blk.accel, wp.GYRO_SENSITIVITY_LSB_PER_DPS[self.gyro_full_scale_dps],
                                      wp.ACCEL_SENSITIVITY_LSB_PER_G[self.accel_range_g])
        flags = PacketFlags(0)
        if not s.sent_any:
            flags |= PacketFlags.SESSION_START
        elif s.resumed:
            flags |= PacketFlags.RESUMED
        if clipped.any():
            flags |= PacketFlags.GYRO_CLIPPED
        data = wp.encode_packet(j, self._sample_times_us(s, i0, i1), counts, flags, s.config_id)
        if self._corrupt_pending > 0:
            self._corrupt_pending -= 1
            self.stats.packets_corrupted += 1
            data = bytes([0xEE]) + data[1:]
        s.sent_any = True
        s.resumed = False
        self.stats.packets_sent += 1
        assert self._central is not None
        for sent in [data] if self.firmware_fault is None else self.firmware_fault(j, data):
            self._central.notify(wp.IMU_DATA_CHAR, sent)

    def _stream_end(self, s: WearableSession) -> None:
        self._log("replay finished")
        self._announce_stream_end()
        self._end_session("replay finished")

    def _announce_stream_end(self) -> None:
        """Tell the central the stream ended by itself (a replay finished)."""
        if self._central is not None and wp.IMU_CONTROL_CHAR in self._notifying:
            self._central.notify(wp.IMU_CONTROL_CHAR, StatusReply(Opcode.STREAM_END, Status.OK, self.config_id).encode())

    async def aclose(self) -> None:
        """Stop streaming and drop any central (for shutdown)."""
        task = self._task
        self._end_session("device shut down")
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
