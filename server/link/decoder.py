"""Packets to samples: sequence and clock unwrapping, loss accounting, the device-time rate estimate.

Transport-independent and synchronous: both link transports feed it the bytes of each data
notification. Rules (docs/protocol.md, "Client rules"):

- Malformed packets (bad length, version, reserved flags, N or config id different from the
  configuration read) are counted and dropped, never fatal.
- A packet whose 16-bit sequence number does not advance is a duplicate: counted and dropped.
- Lost samples = (sequence gap - 1) x N, reported as ``lost_before`` of the next batch, never bridged.
  Gaps longer than the 16-bit sequence range are resolved with the device clock.
- The 32-bit microsecond device clock is unwrapped; the true sample rate is the least-squares slope
  of packet time against sample counter, from device time only (never from arrival time).
- A packet whose sequence number and device time disagree (one of them corrupt: a time stamp 2,000 s
  ahead, a sequence number 30,000 ahead) is an outlier: counted and dropped, never trusted as the new
  clock. Only when RESYNC_AFTER packets in a row agree with each other and not with the stream before
  them does the decoder follow them (the device's clock or counter really jumped), counting the
  packets it dropped meanwhile as lost and keeping the time line continuous.
"""

from __future__ import annotations

import numpy as np

from wearable_protocol import (
    CLOCK_MODULUS,
    SEQ_MODULUS,
    DecodeError,
    DeviceConfig,
    PacketFlags,
    decode_packet,
)

from .base import LinkStats, SampleBatch
from .rate_fit import RateFit

OUTLIER_TOLERANCE_PACKETS = 2.0  # sequence and device time may disagree by this many packets ...
OUTLIER_TOLERANCE_FRACTION = 0.05  # ... plus this share of the gap (the rate estimate's error over a long gap)
RESYNC_AFTER = 3  # consecutive outliers that agree with each other: the stream really jumped; follow it


def _agree(d_packets: int, dt_us: float, fs_hz: float, n: int) -> bool:
    """Whether a sequence step of ``d_packets`` and a device-time step of ``dt_us`` tell the same gap."""
    expected = dt_us * 1e-6 * fs_hz / n
    return abs(d_packets - expected) <= OUTLIER_TOLERANCE_PACKETS + OUTLIER_TOLERANCE_FRACTION * expected


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
        self._suspects: list[tuple[int, int]] = []  # (seq16, unwrapped device time) of the outliers in a row

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

    def _malformed(self, reason: str) -> None:
        self.stats.malformed_packets += 1
        self.stats.malformed_reasons[reason] = self.stats.malformed_reasons.get(reason, 0) + 1

    def _suspected(self, seq16: int, t_us: int) -> bool:
        """Count and drop a packet whose sequence number and device time disagree with the stream's; True when it
        is the RESYNC_AFTER-th in a row that agrees with the one before it (then it is followed, not dropped)."""
        if self._suspects:
            last_seq, last_t = self._suspects[-1]
            d = (seq16 - last_seq) % SEQ_MODULUS
            if not (0 < d < SEQ_MODULUS // 2 and _agree(d, (t_us - last_t) % CLOCK_MODULUS, self.fs_hz, self.config.samples_per_packet)):
                self._suspects = []
        self._suspects.append((seq16, t_us))
        if len(self._suspects) >= RESYNC_AFTER:
            return True
        self._malformed("inconsistent")
        return False

    def feed(self, data: bytes | bytearray) -> SampleBatch | None:
        """Decode one notification; None if it was dropped (malformed or duplicate)."""
        cfg = self.config
        try:
            p = decode_packet(data, expected_n=cfg.samples_per_packet)
        except DecodeError as e:
            self._malformed(e.reason)
            return None
        if p.config_id != cfg.config_id:
            self._malformed("config_id")
            return None
        n = p.n
        lost = 0
        if self._last_seq16 is None:  # first packet on this link
            t_us = p.t_first_us
            packet = p.seq
            if self._expect_new_session and not (p.flags & PacketFlags.RESUMED):
                lost = p.seq * n
            self._t0_us = t_us
        else:
            dt_us = (p.t_first_us - self._last_t_us) % CLOCK_MODULUS
            t_us = self._last_t_us + dt_us
            backwards = dt_us >= CLOCK_MODULUS // 2  # older than the last packet
            if backwards and ((d16 := (p.seq - self._last_seq16) % SEQ_MODULUS) == 0 or d16 >= SEQ_MODULUS // 2):
                self.stats.duplicate_packets += 1  # a stale packet delivered again
                return None
            if p.flags & PacketFlags.SESSION_START and not backwards:
                # the device began a new session (seq restarts): place it after the old one by device time
                self.stats.session_restarts += 1
                fs = self.fs_hz
                end_prev = self._last_packet * n + self._counter_offset + n
                start_new = max(end_prev, self._last_packet * n + self._counter_offset + int(round(dt_us * 1e-6 * fs)))
                self._counter_offset = start_new - p.seq * n
                packet = p.seq
                lost = start_new - end_prev + p.seq * n
                self._fit = RateFit()
            else:
                d = (p.seq - self._last_seq16) % SEQ_MODULUS
                expected = dt_us * 1e-6 * self.fs_hz / n
                d += SEQ_MODULUS * max(0, int(round((expected - d) / SEQ_MODULUS)))
                if not backwards and (d == 0 or d >= SEQ_MODULUS // 2 and expected < SEQ_MODULUS // 4):
                    self.stats.duplicate_packets += 1
                    return None
                if backwards or not _agree(d, dt_us, self.fs_hz, n):
                    # a newer sequence number with device time running backwards, or the two telling different gaps
                    if not self._suspected(p.seq, t_us):
                        return None
                    # the stream moved on together: the packets dropped as outliers meanwhile are lost, and the
                    # jump in device time is left out of the time line, which goes on at the sample rate
                    d = len(self._suspects)
                    self._shift_us += t_us - (self._last_t_us + round(d * n * 1e6 / self.fs_hz))
                    self.stats.resyncs += 1
                packet = self._last_packet + d
                lost = (d - 1) * n
        self._expect_new_session = False
        self._suspects = []
        self._last_seq16 = p.seq
        self._last_packet = packet
        self._last_t_us = t_us
        counter0 = packet * n + self._counter_offset
        self._fit.add(counter0, t_us - self._shift_us)
        fs = self.fs_hz
        assert self._t0_us is not None
        t = (t_us - self._shift_us - self._t0_us) * 1e-6 + np.arange(n) / fs
        raw = p.raw
        gyro = raw[:, :3] / cfg.gyro_lsb_per_dps
        accel = raw[:, 3:] / cfg.accel_lsb_per_g
        g = raw[:, :3]
        saturated = ((g == 32767) | (g == -32768)).any(axis=1)
        st = self.stats
        st.packets += 1
        st.samples += n
        if lost:
            st.lost_samples += lost
            st.lost_packets += lost // n
        st.fs_estimate_hz = fs
        self._last_sample_t_s = float(t[-1])
        return SampleBatch(t, gyro, accel, np.arange(counter0, counter0 + n, dtype=np.int64), lost, fs, saturated)
