"""A simulated Polar Verity Sense: the PMD service with gyroscope and accelerometer measurements."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

import wearable_protocol as wp
from wearable_protocol import Central
from wearable_protocol.models import POLAR_PMD
from wearable_protocol.vendors import polar_pmd as pmd

from ..sources import SampleSource
from ..streaming import WearableSession
from ..wearable import Wearable

# PMD time stamps count ns from 2000-01-01; the device clock's zero is put at 2026-01-01 00:00 UTC.
EPOCH_OFFSET_NS = 820_454_400 * 1_000_000_000
G, A, S = pmd.MeasurementType.GYRO, pmd.MeasurementType.ACC, pmd.SettingType
OFFERS: dict[pmd.MeasurementType, dict[pmd.SettingType, tuple[int, ...]]] = {
    G: {S.SAMPLE_RATE: tuple(int(r) for r in POLAR_PMD.rates_hz), S.RESOLUTION: (16,),
        S.RANGE: POLAR_PMD.gyro_ranges_dps, S.CHANNELS: (3,)},
    A: {S.SAMPLE_RATE: (int(POLAR_PMD.accel_rate_hz or 52),), S.RESOLUTION: (16,), S.RANGE: POLAR_PMD.accel_ranges_g, S.CHANNELS: (3,)},
}
_INVALID = {S.SAMPLE_RATE: pmd.Status.INVALID_SAMPLE_RATE, S.RESOLUTION: pmd.Status.INVALID_RESOLUTION,
            S.RANGE: pmd.Status.INVALID_RANGE, S.CHANNELS: pmd.Status.INVALID_NUMBER_OF_CHANNELS}
MAX_FRAME_SAMPLES = 36  # a delta frame of 36 samples fits a 247-byte MTU whatever the deltas


def _factor(kind: pmd.MeasurementType, full_range: int) -> float:
    """Physical unit per count: deg/s for the gyroscope, mG for the accelerometer (as a float32)."""
    unit = full_range / 32768.0 if kind == G else full_range * 1000.0 / 32768.0
    return pmd.factor_value(pmd.factor_bits(unit))


class PolarWearable(Wearable):
    """A Polar sensor streaming gyroscope frames (delta-compressed, the session's rate) and accelerometer
    frames at 52 Hz, each stamped with the time of its last sample."""

    model = POLAR_PMD
    data_char = pmd.PMD_DATA_CHAR
    gatt_services = pmd.SERVICES

    def _default_name(self) -> str:
        return "Polar Sense " + self.address.replace(":", "")[-8:]

    def __init__(self, source: SampleSource, **kwargs: Any) -> None:
        super().__init__(source, **kwargs)
        self._measuring: dict[pmd.MeasurementType, dict[pmd.SettingType, int]] = {}

    @property
    def samples_per_packet(self) -> int:
        return min(MAX_FRAME_SAMPLES, 9 * max(1, int(round(self.rate_hz / 52.0))))

    device_information = (b"Polar Electro Oy", b"Polar Sense", b"2.1.8")

    def _readable(self) -> dict[str, Callable[[], bytes]]:
        return {pmd.PMD_CONTROL_CHAR: lambda: pmd.encode_features({G, A})}

    def write(self, char_uuid: str, data: bytes) -> None:
        if char_uuid != pmd.PMD_CONTROL_CHAR:
            raise wp.GattError("not_permitted", "Write not permitted")
        if len(data) < 2:
            self._pmd_reply(pmd.ControlResponse(data[0] if data else 0, 0, pmd.Status.INVALID_LENGTH))
            return
        op, kind_id = data[0], data[1] & 0x3F
        if op not in {int(c) for c in pmd.Command}:
            self._pmd_reply(pmd.ControlResponse(op, kind_id, pmd.Status.INVALID_OP_CODE))
            return
        if kind_id not in (G, A):
            self._pmd_reply(pmd.ControlResponse(op, kind_id, pmd.Status.INVALID_MEASUREMENT_TYPE))
            return
        kind = pmd.MeasurementType(kind_id)
        self._pmd_reply(self._execute_pmd(pmd.Command(op), kind, bytes(data[2:])))

    def _execute_pmd(self, op: pmd.Command, kind: pmd.MeasurementType, payload: bytes) -> pmd.ControlResponse:
        def reply(status: pmd.Status, parameters: bytes = b"") -> pmd.ControlResponse:
            return pmd.ControlResponse(int(op), int(kind), int(status), False, parameters)

        if op == pmd.Command.GET_MEASUREMENT_SETTINGS:
            return reply(pmd.Status.SUCCESS, pmd.encode_settings(dict(OFFERS[kind])))
        if op == pmd.Command.STOP_MEASUREMENT:
            self._measuring.pop(kind, None)
            if kind == G:
                self._end_session("stopped by the central")
            return reply(pmd.Status.SUCCESS)
        if kind in self._measuring:
            return reply(pmd.Status.ALREADY_IN_STATE)
        try:
            asked = {k: v[0] for k, v in pmd.parse_settings(payload).items()}
        except wp.DecodeError:
            return reply(pmd.Status.INVALID_PARAMETER)
        for setting, offered in OFFERS[kind].items():
            if setting in asked and asked[setting] not in offered:
                return reply(_INVALID[setting])
        chosen = {k: asked.get(k, v[0]) for k, v in OFFERS[kind].items()}
        if kind == G:
            self._set_sensor(float(chosen[S.SAMPLE_RATE]), int(chosen[S.RANGE]))
        else:
            self.accel_range_g = int(chosen[S.RANGE])
        self._measuring[kind] = chosen
        if kind == G:
            self._start()
        factor = _factor(kind, self.gyro_full_scale_dps if kind == G else self.accel_range_g)
        return reply(pmd.Status.SUCCESS, pmd.encode_settings({S.FACTOR: pmd.factor_bits(factor)}))

    def _pmd_reply(self, response: pmd.ControlResponse) -> None:
        if self._central is not None and pmd.PMD_CONTROL_CHAR in self._notifying:
            self._central.notify(pmd.PMD_CONTROL_CHAR, response.encode())

    def _lose_central(self) -> Central:
        self._measuring.clear()  # the sensor stops its measurements when the link goes
        return super()._lose_central()

    def _announce_stream_end(self) -> None:
        if self._central is not None and pmd.PMD_CONTROL_CHAR in self._notifying:
            self._central.notify(pmd.PMD_CONTROL_CHAR, bytes([pmd.MEASUREMENT_STOPPED, int(G), int(A)]))
        self._measuring.clear()

    def _time_ns(self, s: WearableSession, i: int) -> int:
        return self._sample_times_us(s, i, i + 1) * 1000 + EPOCH_OFFSET_NS

    def _send(self, s: WearableSession, j: int) -> None:
        i0, i1 = j * s.n, (j + 1) * s.n
        blk = self.source.block(i0, i1)
        assert self._central is not None
        gyro = np.clip(np.round(blk.gyro / _factor(G, self.gyro_full_scale_dps)), -32768, 32767)
        frames = [pmd.encode_frame(G, self._time_ns(s, i1 - 1), gyro)]
        if A in self._measuring:
            decimation = max(1, int(round(self.rate_hz / self._measuring[A][S.SAMPLE_RATE])))
            idx = np.arange(i0, i1)
            idx = idx[idx % decimation == 0]
            if idx.size:
                acc = np.clip(np.round(blk.accel[idx - i0] * 1000.0 / _factor(A, self.accel_range_g)), -32768, 32767)
                frames.append(pmd.encode_frame(A, self._time_ns(s, int(idx[-1])), acc))
        if self._corrupt_pending > 0:
            self._corrupt_pending -= 1
            self.stats.packets_corrupted += 1
            frames[0] = frames[0][:11]  # cut inside the reference sample
        s.sent_any = True
        self.stats.packets_sent += 1
        for frame in frames:
            self._central.notify(pmd.PMD_DATA_CHAR, frame)
