"""Why the protocol was not found, when the stages alone cannot say: a recording with no rest anywhere (held
in the hand), or a sample rate that does not fit the recording (a wrong --fs)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calib.errors import ProtocolError
from calib.recording import Recording
from calib.stages.detector import detect_stages
from calib.stages.protocol import ProtocolStages, find_protocol
from calib.stages.stage import Stage
from calib.stages.turn_checks import angle_between_deg
from calib.units import FULL_TURN_DEG

# Output data rates of common MEMS IMUs (ST LSM6/LSM9DS1, TDK InvenSense, Bosch BMI): where a wrong rate
# is looked for, Hz
COMMON_RATES_HZ = (12.5, 25.0, 26.0, 50.0, 52.0, 59.5, 100.0, 102.4, 104.0, 119.0, 200.0, 208.0, 238.0, 400.0, 416.0, 476.0,
                   500.0, 562.5, 800.0, 833.0, 952.0, 1000.0, 1125.0, 1600.0, 1660.0, 3200.0, 3330.0)
REST_NOISE_DPS = (0.01, 0.3)  # how much a MEMS gyroscope lying on a table varies, 1-sigma deg/s
MAX_RATE_SEARCH_SAMPLES = 200_000  # longer recordings are not re-examined at other rates


def quietest_second(rec: Recording) -> tuple[float, float] | None:
    """(start time s, largest per-axis std deg/s) of the quietest 1 s stretch, or None if the recording is shorter."""
    w = max(int(round(rec.fs)), 8)
    n = len(rec)
    if n < w + 1:
        return None
    c1 = np.vstack([np.zeros(3), np.cumsum(rec.gyro, axis=0)])
    c2 = np.vstack([np.zeros(3), np.cumsum(rec.gyro**2, axis=0)])
    mean = (c1[w:] - c1[:-w]) / w
    var = np.maximum((c2[w:] - c2[:-w]) / w - mean**2, 0.0)
    spread = np.sqrt(var.max(axis=1))
    i = int(np.argmin(spread))
    return float(rec.t[i]), float(spread[i])


def never_at_rest(rec: Recording) -> tuple[float, float] | None:
    """The quietest second (start s, largest per-axis std deg/s) when even it varies more than a gyroscope lying on a
    table (the device was held in the hand throughout); None when the recording has a quiet second or is too short."""
    quiet = quietest_second(rec)
    return quiet if quiet is not None and quiet[1] > REST_NOISE_DPS[1] else None


def quiet_text(quiet: tuple[float, float]) -> str:
    """The sentence on a recording's quietest second against what rest looks like, for refusals."""
    return (f"its quietest second, at {quiet[0]:.1f} s, varies by {quiet[1]:.2f} deg/s, where a gyroscope lying on a table "
            f"varies by about {REST_NOISE_DPS[0]:g}-{REST_NOISE_DPS[1]:g} deg/s")


def rate_that_fits(rec: Recording) -> float | None:
    """The common IMU rate at which the protocol is found in this recording (its times rescaled) with its turns
    measuring closest to 360 degrees, or None."""
    if len(rec) > MAX_RATE_SEARCH_SAMPLES:
        return None
    fs = rec.fs
    fits: list[tuple[float, float]] = []
    for rate in COMMON_RATES_HZ:
        if abs(rate / fs - 1.0) < 0.1:
            continue  # about the rate already used
        scaled = replace(rec, t=rec.t[0] + (rec.t - rec.t[0]) * fs / rate,
                         meta=replace(rec.meta, sample_rate_hz=rate if rec.meta.sample_rate_hz else None))
        try:
            proto = find_protocol(detect_stages(scaled))
        except ProtocolError:
            continue
        except Exception:  # a rescaled recording the detector cannot take is no evidence either way
            continue
        turns = list(proto.turns.values())
        if _turns_come_back(scaled, turns):
            fits.append((float(np.mean([abs(np.log(abs(t.angle_deg or 1.0) / FULL_TURN_DEG)) for t in turns])), rate))
    return min(fits)[1] if fits else None


def _turns_come_back(rec: Recording, turns: list[Stage], max_deg: float = 20.0) -> bool:
    """Whether gravity points the same way before and after each turn (a full turn puts the device back; a quarter
    turn read at four times the rate does not). True when there is no accelerometer to tell."""
    if rec.accel is None:
        return True
    w = max(int(0.3 * rec.fs), 3)
    for s in turns:
        before = rec.accel[max(0, s.start - w) : s.start].mean(axis=0)
        after = rec.accel[s.end : s.end + w].mean(axis=0)
        if not (np.all(np.isfinite(before)) and np.all(np.isfinite(after))) or s.start < 1 or s.end + 1 > len(rec):
            continue
        if angle_between_deg(before, after) > max_deg:
            return False
    return True


def find_protocol_in(rec: Recording, stages: list[Stage]) -> ProtocolStages:
    """calib.stages.find_protocol, whose ProtocolError also says, where it can, why the protocol is not there:
    no rest anywhere, or a sample rate that does not fit; and carries the stages that were found."""
    try:
        return find_protocol(stages)
    except ProtocolError as exc:
        message, code = str(exc), exc.code
        rate = rate_that_fits(rec)
        quiet = quietest_second(rec) if rate is None and not any(s.kind == "still" for s in stages) else None
        if quiet is not None:
            if quiet[1] > REST_NOISE_DPS[1]:
                code = "no_rest"
                message = (f"there is no rest anywhere in the recording (was the device held in the hand?): {quiet_text(quiet)}. "
                           "Put the device down, still, for about 3 s before, between and after the turns. " + message)
            else:
                message = (f"no rest of at least 1 s was found, although the recording is quiet at {quiet[0]:.1f} s "
                           f"({quiet[1]:.2f} deg/s, as at rest): if its rests last seconds, the sample rate ({rec.fs:g} Hz) "
                           "may be wrong. " + message)
        if rate is not None:
            code = "sample_rate_suspect"
            message = (f"the sample rate looks wrong: read at {rate:g} Hz instead of {rec.fs:g} Hz, the recording holds the "
                       f"protocol. Give the rate the device recorded at (on the command line: --fs {rate:g}). " + message)
        raise ProtocolError(message, code=code, stages=stages) from None
