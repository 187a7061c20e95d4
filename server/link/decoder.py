"""Packets to samples: sequence and clock unwrapping, loss accounting, the device-time rate estimate.

Transport-independent and synchronous: both link transports feed it the bytes of each data
notification. Rules (docs/protocol.md, "Client rules"):

- Malformed packets (bad length, version, reserved flags, N or config id different from the
  configuration read) are counted and dropped, never fatal.
- A packet whose 16-bit sequence number does not advance is a duplicate: counted and dropped; it came in the place
  of a new packet, so a gap it leaves counts with the refused ones.
- Missing samples = (sequence gap - 1) x N, never bridged. Those the packets refused since the last good one
  account for are the wearable's (``refused_before`` of the next batch: its firmware sent them malformed); the rest
  were lost on the radio (``lost_before``). Gaps longer than the 16-bit sequence range are resolved with the device
  clock.
- A packet that comes up to REORDER_WINDOW packets after a gap waits for the next one: when that is the missing
  packet (the link delivered the two out of order), both are delivered in order and nothing was lost.
- The 32-bit microsecond device clock is unwrapped; the true sample rate is the least-squares slope
  of packet time against sample counter, from device time only (never from arrival time).
- A packet whose sequence number and device time disagree (one of them corrupt: a time stamp 2,000 s
  ahead, a sequence number 30,000 ahead) is an outlier, and so, until confirmed, is one after a gap longer
  than LONG_GAP_S: held back, never trusted as the new clock. When RESYNC_AFTER such packets in a row agree
  with each other, the stream really went there (a long outage, or the device's clock or counter jumped) and
  they are all delivered; otherwise each is counted (``inconsistent``) and dropped. A jumped clock is left out
  of the time line, which stays continuous.
"""

from __future__ import annotations

import numpy as np

from wearable_protocol import (
    CLOCK_MODULUS,
    SEQ_MODULUS,
    DecodeError,
    DeviceConfig,
    Packet,
    PacketFlags,
    decode_packet,
)

from .base import LinkStats, SampleBatch
from .outliers import LONG_GAP_S, TOLERANCE_FRACTION, TOLERANCE_SAMPLES, Suspects
from .rate_fit import RateFit

REORDER_WINDOW = 2  # packets: a gap this short may be a packet delivered late, out of order; wait one packet for it


def _agree(d_packets: int, dt_us: float, fs_hz: float, n: int) -> bool:
    """Whether a sequence step of ``d_packets`` and a device-time step of ``dt_us`` tell the same gap."""
    expected = dt_us * 1e-6 * fs_hz  # samples
    return abs(d_packets * n - expected) <= TOLERANCE_SAMPLES + TOLERANCE_FRACTION * expected


class StreamDecoder:
    """Decodes the data notifications of one link into SampleBatches; counts into ``stats``."""

    def __init__(self, config: DeviceConfig, stats: LinkStats | None = None) -> None:
        self.stats = stats if stats is not None else LinkStats()
        self.config = config
        self._fit = RateFit()
        self._t0_us: int | None = None  # unwrapped device time of the first sample received
        self._last_seq16: int | None = None
        self._last_packet: int = 0  # unwrapped packet index of the last packet
        self._last_t_us: int = 0  # unwrapped device time of the last packet's first sample
        self._counter_offset = 0  # sample counter = packet index * N + offset (changes at session restarts)
        self._expect_new_session = False
        self._last_sample_t_s: float | None = None
        self._shift_us = 0  # device-clock time left out of the time line by resyncs (a clock that jumped)
        # the packets held back in a row: (packet, unwrapped device time, its gap in packets when that agreed with time)
        self._suspects: Suspects[tuple[Packet, int, int | None]] = Suspects()
        self._waiting: Packet | None = None  # a packet after a short gap, waiting one packet for the missing one
        self._refused_since = 0  # packets refused since the last one delivered: they explain a gap before the next
        self._steps = np.empty(0)  # 0, 1, ..., n-1 for a packet of n samples

    @property
    def fs_hz(self) -> float:
        return self._fit.rate(self.config.sample_rate_hz)

    @property
    def last_t_s(self) -> float | None:
        """Device time (s) of the last sample decoded."""
        return self._last_sample_t_s

    def set_config(self, config: DeviceConfig) -> None:
        """The configuration changed (read again after a reconnection or a configure())."""
        self.config = config

    def begin(self, new_session: bool) -> None:
        """The central just sent START: ``new_session`` if the device had no session to resume, so the
        first packet received should be seq 0 (packets missing before it count as lost)."""
        self._expect_new_session = new_session

    def feed(self, data: bytes | bytearray) -> SampleBatch | None:
        """Decode one notification; None if it was dropped (malformed or duplicate) or is held back (an outlier)."""
        cfg = self.config
        try:
            p = decode_packet(data, expected_n=cfg.samples_per_packet)
        except DecodeError as e:
            self._refuse(e.reason)
            return None
        if p.config_id != cfg.config_id:
            self._refuse("config_id")
            return None
        waiting, self._waiting = self._waiting, None
        out: list[SampleBatch] = []
        if waiting is not None and not _comes_before(p, waiting):
            out += self._deliver(self._place(waiting))  # not the missing packet: the gap before ``waiting`` stands
            waiting = None
        if waiting is None:
            out += self._deliver(self._place_or_wait(p))
        else:  # the packet the gap was waiting for, delivered late: both in order
            out += self._deliver(self._place(p))
            out += self._deliver(self._place(waiting))
        return SampleBatch.concat(out) if out else None

    def _refuse(self, reason: str, count: int = 1) -> None:
        self.stats.refused(reason, count)
        self._refused_since = max(0, self._refused_since + count)

    def _duplicate(self) -> None:
        """A packet that repeats one already delivered: dropped. It came in the place of a new one, as the wearable
        sent it (a BLE link never delivers a notification twice): a gap it leaves is the wearable's, like a refused
        packet's, and waits for nothing."""
        self.stats.duplicate_packets += 1
        self._refused_since += 1

    def _deliver(self, placed: list[tuple[Packet, int, int, int]]) -> list[SampleBatch]:
        return [self._emit(placed)] if placed else []

    def _place_or_wait(self, p: Packet) -> list[tuple[Packet, int, int, int]]:
        """``_place``, except that a packet after a gap of at most REORDER_WINDOW packets that no refused packet
        explains waits for the next packet (empty), which may be the one missing."""
        if self._last_seq16 is None or p.flags & PacketFlags.SESSION_START:
            return self._place(p)
        placed = self._place(p)
        if len(placed) == 1 and 0 < placed[0][3] <= REORDER_WINDOW * p.n and self._refused_since * p.n < placed[0][3]:
            self._waiting = p  # placing a packet after an ordinary gap changes nothing: it is placed again later
            return []
        return placed

    def _place(self, p: Packet) -> list[tuple[Packet, int, int, int]]:
        """Where ``p`` goes: (packet, unwrapped packet index, unwrapped device time, samples lost before it) for it and
        any packets held back with it; empty when it is dropped or held back."""
        n = p.n
        if self._last_seq16 is None:  # first packet on this link
            lost = p.seq * n if self._expect_new_session and not (p.flags & PacketFlags.RESUMED) else 0
            self._t0_us = p.t_first_us
            return [(p, p.seq, p.t_first_us, lost)]
        dt_us = (p.t_first_us - self._last_t_us) % CLOCK_MODULUS
        t_us = self._last_t_us + dt_us
        backwards = dt_us >= CLOCK_MODULUS // 2  # older than the last packet
        if backwards and ((d16 := (p.seq - self._last_seq16) % SEQ_MODULUS) == 0 or d16 >= SEQ_MODULUS // 2):
            self._duplicate()  # a stale packet delivered again
            return []
        fs = self.fs_hz
        if p.flags & PacketFlags.SESSION_START and not backwards:
            # the device began a new session (seq restarts): place it after the old one by device time
            self.stats.session_restarts += 1
            end_prev = self._last_packet * n + self._counter_offset + n
            start_new = max(end_prev, self._last_packet * n + self._counter_offset + int(round(dt_us * 1e-6 * fs)))
            self._counter_offset = start_new - p.seq * n
            self._fit = RateFit()
            return [(p, p.seq, t_us, start_new - end_prev + p.seq * n)]
        d = (p.seq - self._last_seq16) % SEQ_MODULUS
        expected = dt_us * 1e-6 * fs / n
        d += SEQ_MODULUS * max(0, int(round((expected - d) / SEQ_MODULUS)))
        if not backwards and (d == 0 or d >= SEQ_MODULUS // 2 and expected < SEQ_MODULUS // 4):
            self._duplicate()
            return []
        agrees = not backwards and _agree(d, dt_us, fs, n)
        if agrees and d * n < LONG_GAP_S * fs:
            return [(p, self._last_packet + d, t_us, (d - 1) * n)]
        return self._hold_back(p, t_us, d if agrees else None)

    def _hold_back(self, p: Packet, t_us: int, d: int | None) -> list[tuple[Packet, int, int, int]]:
        """An outlier, or a packet after a long gap: counted and held back until RESYNC_AFTER in a row agree with each
        other; then all of them, placed after a gap that was real (``d`` of the first) or after a clock that jumped."""
        n = p.n
        fs = self.fs_hz

        def follows(prev: tuple[Packet, int, int | None], cur: tuple[Packet, int, int | None]) -> bool:
            step = (cur[0].seq - prev[0].seq) % SEQ_MODULUS
            return 0 < step < SEQ_MODULUS // 2 and _agree(step, (cur[1] - prev[1]) % CLOCK_MODULUS, fs, n)

        self._refuse("inconsistent")
        if not self._suspects.add((p, t_us, d), follows):
            return []
        held = self._suspects.items
        self._suspects.clear()
        self._refuse("inconsistent", -len(held))  # confirmed: delivered, not dropped
        first, first_t, first_d = held[0]
        if first_d is None:  # the device's clock or counter jumped: the time line goes on at the sample rate
            self.stats.resyncs += 1
            self._shift_us += first_t - (self._last_t_us + round(n * 1e6 / fs))
            first_d = 1
        out, packet, last = [], self._last_packet + first_d, self._last_packet
        for k, (q, tq, _) in enumerate(held):
            if k:
                packet += (q.seq - held[k - 1][0].seq) % SEQ_MODULUS
            out.append((q, packet, tq, (packet - last - 1) * n))
            last = packet
        return out

    def _emit(self, placed: list[tuple[Packet, int, int, int]]) -> SampleBatch:
        """The samples of packets placed in order, as one batch; the stream's state moved on past the last."""
        cfg = self.config
        self._expect_new_session = False
        self._suspects.clear()
        parts = []
        lost_total = refused_total = 0
        st = self.stats
        assert self._t0_us is not None
        for p, packet, t_us, missing in placed:
            n = p.n
            self._last_seq16, self._last_packet, self._last_t_us = p.seq, packet, t_us
            counter0 = packet * n + self._counter_offset
            self._fit.add(counter0, t_us - self._shift_us)
            parts.append((t_us - self._shift_us - self._t0_us, p.raw, counter0))
            refused = min(missing, self._refused_since * n)  # the wearable's own malformed packets, not the radio's
            self._refused_since = 0
            lost = missing - refused
            lost_total += lost
            refused_total += refused
            st.packets += 1
            st.samples += n
            if lost:
                st.lost_samples += lost
                st.lost_packets += lost // n
        fs = self.fs_hz
        if len(parts) == 1:  # the usual case: one packet, no arrays to join
            t0_us, raw, counter0 = parts[0]
            n = raw.shape[0]
            t = t0_us * 1e-6 + self._offsets(n, fs)
            counter = np.arange(counter0, counter0 + n, dtype=np.int64)
        else:
            raw = np.concatenate([x[1] for x in parts])
            t = np.concatenate([x[0] * 1e-6 + self._offsets(x[1].shape[0], fs) for x in parts])
            counter = np.concatenate([np.arange(x[2], x[2] + x[1].shape[0], dtype=np.int64) for x in parts])
        st.fs_estimate_hz = fs
        self._last_sample_t_s = float(t[-1])
        g = raw[:, :3]
        saturated = ((g == 32767) | (g == -32768)).any(axis=1)
        return SampleBatch(t, g / cfg.gyro_lsb_per_dps, raw[:, 3:] / cfg.accel_lsb_per_g, counter, lost_total, fs,
                           saturated, refused_before=refused_total)

    def _offsets(self, n: int, fs: float) -> np.ndarray:
        """The times (s) of a packet's n samples after its first, at fs Hz."""
        if self._steps.size != n:  # the same n packet after packet
            self._steps = np.arange(n, dtype=float)
        return self._steps / fs


def _comes_before(p: Packet, waiting: Packet) -> bool:
    """Whether ``p`` is an earlier packet than ``waiting`` by sequence number (one the gap before it was missing)."""
    return 0 < (waiting.seq - p.seq) % SEQ_MODULUS < SEQ_MODULUS // 2
