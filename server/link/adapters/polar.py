"""Polar Measurement Data (Polar Verity Sense, OH1): gyroscope and accelerometer frames with the device's
time stamps (``wearable_protocol.vendors.polar_pmd`` holds the byte layouts and their sources).

Settings are negotiated: the adapter asks the device which rates and ranges it offers for each
measurement and starts the gyroscope at the model's streaming rate (or the fastest offered below it)
with the smallest range a brisk hand turn does not clip; the start reply's FACTOR scales the frames.
Frames carry no counter: a gap in the time stamps longer than the frame's samples is counted as lost
samples. The accelerometer runs at its own rate (52 Hz on the Verity Sense) and is interpolated onto the
gyroscope's sample times.
"""

from __future__ import annotations

import logging

import numpy as np

from wearable_protocol import DecodeError, DeviceConfig
from wearable_protocol.models import POLAR_PMD, hand_motion_accel_range, hand_turn_range
from wearable_protocol.vendors import polar_pmd as pmd

from ..base import CommandError, ConnectError, LinkStats, SampleBatch
from ..outliers import LONG_GAP_S, TOLERANCE_FRACTION, TOLERANCE_SAMPLES, Suspects
from ..rate_fit import RateFit
from .base import Adapter, vendor_config

log = logging.getLogger(__name__)

ACC_HOLD_S = 0.5  # gyro samples wait at most this long for the accelerometer samples around them
ACC_KEEP = 256  # accelerometer samples kept for interpolation
INT16_LIMITS = (-32768, 32767)


def _fastest_up_to(offered: tuple[int, ...], wanted: float) -> int:
    """The fastest offered rate at or below ``wanted``; the slowest offered when all are faster."""
    below = [v for v in sorted(offered) if v <= wanted]
    return below[-1] if below else min(offered)


class PolarDecoder:
    """PMD data frames to SampleBatches: gyroscope samples with interpolated accelerometer readings."""

    def __init__(self, stats: LinkStats, gyro_rate_hz: float, gyro_factor: float, acc_rate_hz: float,
                 acc_factor_mg: float) -> None:
        self.stats = stats
        self.gyro_rate_hz = gyro_rate_hz
        self.gyro_factor = gyro_factor
        self.acc_rate_hz = acc_rate_hz
        self.acc_factor_g = acc_factor_mg / 1000.0
        self._fit = RateFit()
        self._t0_ns: int | None = None
        self._last_ns: int | None = None
        self._counter = 0
        self._acc_last_ns: int | None = None
        self._acc_t = np.zeros(0, dtype=np.int64)
        self._acc = np.zeros((0, 3))
        self._pending: list[tuple[np.ndarray, np.ndarray, np.ndarray, int, np.ndarray]] = []
        self.last_t_s: float | None = None
        self._suspects: Suspects[pmd.Frame] = Suspects()  # gyro frames held back in a row (server.link.outliers)

    @property
    def fs_hz(self) -> float:
        return self._fit.rate(self.gyro_rate_hz)

    def feed(self, data: bytes) -> list[SampleBatch]:
        """Decode one data notification; the batches it completes (none while waiting for the accelerometer)."""
        try:
            frame = pmd.decode_frame(data)
        except DecodeError as e:
            self.stats.refused(e.reason)
            return []
        if frame.measurement == pmd.MeasurementType.ACC:
            self._add_acc(frame)
        elif frame.measurement == pmd.MeasurementType.GYRO:
            self._add_gyro(frame)
        else:
            self.stats.refused("measurement")
            return []
        return self._flush()

    def drain(self) -> list[SampleBatch]:
        """The gyro samples still waiting for the accelerometer, with its last reading held (the link dropped:
        what came before the gap goes out before it)."""
        return self._flush(everything=True)

    def _times(self, last_ns: int | None, frame_ns: int, n: int, fs: float) -> tuple[np.ndarray, int]:
        """Sample times (ns) of a frame and the samples lost before it, from the time stamps."""
        if last_ns is None:
            return pmd.sample_times_ns(0, frame_ns, n, fs), 0
        lost = max(0, int(round((frame_ns - last_ns) * 1e-9 * fs)) - n)
        if lost == 0:
            return pmd.sample_times_ns(last_ns, frame_ns, n, fs), 0
        return np.round(frame_ns - (n - 1 - np.arange(n)) * 1e9 / fs).astype(np.int64), lost

    def _add_acc(self, frame: pmd.Frame) -> None:
        if self._acc_last_ns is not None and frame.timestamp_ns <= self._acc_last_ns:
            self.stats.refused("clock")
            return
        t, _ = self._times(self._acc_last_ns, frame.timestamp_ns, len(frame.values), self.acc_rate_hz)
        self._acc_last_ns = frame.timestamp_ns
        self._acc_t = np.concatenate([self._acc_t, t])[-ACC_KEEP:]
        self._acc = np.concatenate([self._acc, frame.scaled(self.acc_factor_g)])[-ACC_KEEP:]

    def _add_gyro(self, frame: pmd.Frame) -> None:
        if self._last_ns is not None and not self._fits(frame):
            return
        self._add_gyro_frame(frame)

    def _fits(self, frame: pmd.Frame) -> bool:
        """Whether a gyro frame continues the stream. One stamped at or before the last is a duplicate (a replay);
        one far ahead of it (LONG_GAP_S: a corrupt time stamp, or a long outage) is held back until RESYNC_AFTER
        frames in a row follow each other from it, then all are delivered; a frame that goes on from the old
        stream instead drops the held ones (counted ``inconsistent``), so one bad time stamp costs one frame."""
        assert self._last_ns is not None
        gap_s = (frame.timestamp_ns - self._last_ns) * 1e-9
        if gap_s <= 0:
            self.stats.duplicate_packets += 1
            return False
        if gap_s < LONG_GAP_S:
            self._suspects.clear()
            return True
        fs = self.fs_hz

        def follows(prev: pmd.Frame, cur: pmd.Frame) -> bool:
            step_s = (cur.timestamp_ns - prev.timestamp_ns) * 1e-9
            return abs(step_s * fs - len(cur.values)) <= TOLERANCE_SAMPLES + TOLERANCE_FRACTION * len(cur.values)

        self.stats.refused("inconsistent")
        if not self._suspects.add(frame, follows):
            return False
        held = self._suspects.items
        self._suspects.clear()
        self.stats.refused("inconsistent", -len(held))  # confirmed: a real gap, delivered
        for f in held[:-1]:
            self._add_gyro_frame(f)
        return True

    def _add_gyro_frame(self, frame: pmd.Frame) -> None:
        n = len(frame.values)
        t, lost = self._times(self._last_ns, frame.timestamp_ns, n, self.fs_hz)
        self._last_ns = frame.timestamp_ns
        if self._t0_ns is None:
            self._t0_ns = int(t[0])
        counter0 = self._counter + lost
        self._counter = counter0 + n
        self._fit.add(self._counter - 1, frame.timestamp_ns // 1000)
        raw = frame.values
        saturated = ((raw == INT16_LIMITS[0]) | (raw == INT16_LIMITS[1])).any(axis=1)
        self._pending.append((t, frame.scaled(self.gyro_factor), np.arange(counter0, counter0 + n, dtype=np.int64), lost,
                              saturated))
        st = self.stats
        st.packets += 1
        st.samples += n
        if lost:
            st.lost_samples += lost
            st.lost_packets += max(1, lost // n)

    def _flush(self, everything: bool = False) -> list[SampleBatch]:
        out: list[SampleBatch] = []
        while self._pending:
            t, gyro, seq, lost, saturated = self._pending[0]
            covered = self._acc_t.size and self._acc_t[-1] >= t[-1]
            waited = everything or (self._pending[-1][0][-1] - t[0]) * 1e-9 >= ACC_HOLD_S
            if not covered and not (waited and self._acc_t.size):
                break
            self._pending.pop(0)
            accel = np.column_stack([np.interp(t, self._acc_t, self._acc[:, k]) for k in range(3)])
            assert self._t0_ns is not None
            fs = self.fs_hz
            self.stats.fs_estimate_hz = fs
            t_s = (t - self._t0_ns) * 1e-9
            self.last_t_s = float(t_s[-1])
            out.append(SampleBatch(t_s, gyro, accel, seq, lost, fs, saturated))
        return out


class PolarAdapter(Adapter):
    """A Polar sensor's PMD service: gyroscope and accelerometer streams."""

    model = POLAR_PMD
    data_char = pmd.PMD_DATA_CHAR

    def _setup(self) -> None:
        self._settings: dict[pmd.MeasurementType, dict[pmd.SettingType, int]] = {}
        self._factors: dict[pmd.MeasurementType, float] = {}
        self._decoder: PolarDecoder | None = None
        self._offered: dict[pmd.MeasurementType, pmd.Settings] = {}

    async def open(self) -> DeviceConfig:
        if not self.io.has(pmd.PMD_CONTROL_CHAR):
            raise ConnectError("the device has no PMD control point; is it a Polar sensor with motion data?")
        try:
            features = pmd.parse_features(await self.io.read(pmd.PMD_CONTROL_CHAR))
        except DecodeError as e:
            raise ConnectError(f"the Polar sensor's feature list is unreadable ({e})") from e
        missing = {pmd.MeasurementType.GYRO, pmd.MeasurementType.ACC} - features
        if missing:
            raise ConnectError("this Polar sensor does not stream " + " and ".join(sorted(m.name.lower() for m in missing))
                               + " data: use a Verity Sense or OH1")
        await self.io.subscribe(pmd.PMD_CONTROL_CHAR, self._on_control)
        for kind in (pmd.MeasurementType.GYRO, pmd.MeasurementType.ACC):
            reply = await self._command(pmd.Command.GET_MEASUREMENT_SETTINGS, kind)
            self._offered[kind] = pmd.parse_settings(reply.parameters)
        if not self._settings:
            await self.configure(sample_rate_hz=None, gyro_full_scale_dps=None, accel_range_g=None)
        return self._config()

    def _offer(self, kind: pmd.MeasurementType, setting: pmd.SettingType) -> tuple[int, ...]:
        values = self._offered.get(kind, {}).get(setting)
        if not values:
            raise ConnectError(f"the Polar sensor offers no {setting.name.lower()} for {kind.name.lower()}")
        return values

    async def configure(self, *, sample_rate_hz: float | None, gyro_full_scale_dps: int | None,
                        accel_range_g: int | None) -> DeviceConfig:
        G, A, S = pmd.MeasurementType.GYRO, pmd.MeasurementType.ACC, pmd.SettingType
        rates, ranges = self._offer(G, S.SAMPLE_RATE), self._offer(G, S.RANGE)
        for asked, offered, what in ((sample_rate_hz, rates, "rate"), (gyro_full_scale_dps, ranges, "gyro range"),
                                     (accel_range_g, self._offer(A, S.RANGE), "accelerometer range")):
            if asked is not None and int(asked) not in offered:
                raise CommandError(f"the Polar sensor offers no {what} {asked:g}: choose one of "
                                   + ", ".join(str(v) for v in offered))
        rate = int(sample_rate_hz) if sample_rate_hz is not None else _fastest_up_to(rates, self.model.stream_rate_hz)
        gyro_range = int(gyro_full_scale_dps) if gyro_full_scale_dps is not None else hand_turn_range(ranges)
        acc_rate = _fastest_up_to(self._offer(A, S.SAMPLE_RATE), rate)
        acc_range = int(accel_range_g) if accel_range_g is not None else hand_motion_accel_range(self._offer(A, S.RANGE))
        self._settings = {
            G: {S.SAMPLE_RATE: rate, S.RESOLUTION: 16, S.RANGE: gyro_range, S.CHANNELS: 3},
            A: {S.SAMPLE_RATE: acc_rate, S.RESOLUTION: 16, S.RANGE: acc_range, S.CHANNELS: 3},
        }
        self._factors = {}
        self._decoder = None
        return self._config()

    def _config(self, streaming: bool = False) -> DeviceConfig:
        G, A, S = pmd.MeasurementType.GYRO, pmd.MeasurementType.ACC, pmd.SettingType
        g, a = self._settings[G], self._settings[A]
        gyro_factor = self._factors.get(G, g[S.RANGE] / 32768.0)
        acc_factor_mg = self._factors.get(A, a[S.RANGE] * 1000.0 / 32768.0)
        cfg = vendor_config(g[S.SAMPLE_RATE], g[S.RANGE], a[S.RANGE], 0, 1.0 / gyro_factor, 1000.0 / acc_factor_mg, streaming)
        self.config = cfg
        return cfg

    async def start(self, *, resume: bool) -> None:
        await self.io.subscribe(pmd.PMD_DATA_CHAR, self._on_data)
        for kind in (pmd.MeasurementType.ACC, pmd.MeasurementType.GYRO):
            reply = await self._command(pmd.Command.REQUEST_MEASUREMENT_START, kind,
                                        pmd.encode_settings(dict(self._settings[kind])), allow_already=resume)
            factor = pmd.parse_settings(reply.parameters).get(pmd.SettingType.FACTOR) if reply.parameters else None
            if factor:
                self._factors[kind] = pmd.factor_value(factor[0])
        cfg = self._config(streaming=True)
        if self._decoder is None:
            S = pmd.SettingType
            self._decoder = PolarDecoder(self.stats, cfg.sample_rate_hz, 1.0 / cfg.gyro_lsb_per_dps,
                                         float(self._settings[pmd.MeasurementType.ACC][S.SAMPLE_RATE]),
                                         1000.0 / cfg.accel_lsb_per_g)

    async def stop(self) -> None:
        for kind in (pmd.MeasurementType.GYRO, pmd.MeasurementType.ACC):
            await self._command(pmd.Command.STOP_MEASUREMENT, kind, allow_already=True)
        await self.io.unsubscribe(pmd.PMD_DATA_CHAR)
        self._decoder = None

    async def _command(self, command: pmd.Command, kind: pmd.MeasurementType, settings: bytes = b"",
                       allow_already: bool = False) -> pmd.ControlResponse:
        what = f"{command.name} for {kind.name.lower()}"
        reply: pmd.ControlResponse = await self._exchange((int(command), int(kind)), pmd.PMD_CONTROL_CHAR,
                                                          pmd.encode_command(command, kind, settings), what)
        ok = reply.status == pmd.Status.SUCCESS or (allow_already and reply.status == pmd.Status.ALREADY_IN_STATE)
        if not ok:
            raise CommandError(f"the Polar sensor refused {what}: {reply.status_name.replace('_', ' ')}")
        return reply

    def link_lost(self) -> None:
        super().link_lost()
        if self._decoder is not None:
            for batch in self._decoder.drain():
                self.sink.batch(batch)

    def _on_control(self, data: bytes) -> None:
        if data and data[0] == pmd.MEASUREMENT_STOPPED:
            self.sink.ended("the Polar sensor stopped the measurement")
            return
        try:
            reply = pmd.ControlResponse.decode(data)
        except DecodeError as e:
            log.warning("unreadable PMD reply %r: %s", bytes(data), e)
            return
        self._answer((reply.opcode, reply.measurement), reply)

    def _on_data(self, data: bytes) -> None:
        if self._decoder is None:
            return
        for batch in self._decoder.feed(bytes(data)):
            self.last_t_s = self._decoder.last_t_s
            self.sink.batch(batch)
