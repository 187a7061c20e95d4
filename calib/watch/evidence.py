"""What a study recording holds that can test a calibration: its rests (zero true rate: the corrected reading there
is the bias's error) and the re-orientations between two consecutive rests short enough to integrate (the
accelerometer's gravity at both ends measures their rotation, up to a turn about the vertical). Longer motion between
two rests (walking, a restless hour) is left out and counted."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.apply.correction import Correction
from calib.errors import ProtocolError
from calib.estimators.accel import AccelCalibration, AccelCalibrationError, apply_model, calibrate_accelerometer, rest_spans
from calib.noise.rests import noise_colour
from calib.recording import Recording
from calib.stages.detector import detect_stages

MAX_REORIENTATION_S = 10.0  # a motion between two rests longer than this is not integrated (walking, fidgeting)
MIN_REST_S = 4.0  # a rest shorter than this is not used: its mean is its settling
MIN_RESTS = 3
PIECE_S = 30.0  # the bias is read over pieces of a rest at most this long: a change inside a long rest is placed in time
EDGE_S = 5.0  # ... and over each rest's first and last seconds, for the motions on either side (a warming bias moves)
SE_FLOOR_DPS = 1e-6  # a mean's standard error is never taken as less (a noiseless simulation)


@dataclass(frozen=True)
class Rest:
    """One rest: samples [start, end) averaged, the corrected rate's mean there (deg/s: the bias's error) and its
    standard error, the temperature (degC, None without a channel) and the mean specific force (g, None without an
    accelerometer)."""

    start: int
    end: int
    t_mid_s: float
    bias_dps: np.ndarray
    bias_se_dps: np.ndarray
    temperature_c: float | None
    gravity: np.ndarray | None
    edges_dps: tuple[np.ndarray, np.ndarray]  # the bias's error over its first and last EDGE_S
    edges_se_dps: tuple[np.ndarray, np.ndarray]


@dataclass(frozen=True)
class Reorientation:
    """A motion between rests ``before`` and ``after`` (indices into the rests), samples [start, end)."""

    before: int
    after: int
    start: int
    end: int
    duration_s: float
    temperature_c: float | None


@dataclass(frozen=True)
class Evidence:
    """The recording's rests and re-orientations, and the motion left out (count, seconds)."""

    rec: Recording
    correction: Correction
    rests: list[Rest]
    pieces: list[Rest]  # the rests cut into pieces of at most PIECE_S, for the bias in time
    reorientations: list[Reorientation]
    left_out: int
    left_out_s: float
    noise_dps: np.ndarray  # the raw readings' noise std at rest, per axis
    accel: AccelCalibration | None  # the accelerometer's calibration the gravity directions were read with

    @property
    def has_temperature(self) -> bool:
        return self.rests[0].temperature_c is not None


def _mean_temperature(rec: Recording, i: int, j: int) -> float | None:
    if rec.temp is None:
        return None
    seg = rec.temp[i:j]
    return float(np.nanmean(seg)) if np.isfinite(seg).any() else None


def gather(rec: Recording, correction: Correction) -> Evidence:
    """The rests and re-orientations of ``rec`` read with ``correction``; ProtocolError with fewer than MIN_RESTS rests."""
    stills = [s for s in detect_stages(rec) if s.kind == "still" and s.end_s - s.start_s >= MIN_REST_S]
    if len(stills) < MIN_RESTS:
        raise ProtocolError(f"the recording has {len(stills)} rest(s) of at least {MIN_REST_S:g} s; watching a calibration "
                            f"needs at least {MIN_RESTS}: a recording where the wearable lies still now and then (on the "
                            "table before it is put on, lying, sitting)", code="no_rest")
    spans = rest_spans(stills, rec.fs)
    rate, corrected_accel = correction.apply(rec.gyro, rec.accel)
    colour = noise_colour(rec.gyro, spans)
    pooled = [rec.gyro[i:j] - rec.gyro[i:j].mean(axis=0) for i, j in spans]
    noise = np.sqrt(np.mean(np.concatenate(pooled) ** 2, axis=0))
    accel = None if corrected_accel is not None else _accelerometer(rec, stills)
    rests = [_rest(rec, rate, corrected_accel, accel, colour, i, j) for i, j in spans]
    piece = max(int(PIECE_S * rec.fs), 1)
    pieces = [_rest(rec, rate, corrected_accel, accel, colour, p, min(p + piece, j)) for i, j in spans
              for p in range(i, j, piece) if min(p + piece, j) - p >= piece // 3 or p == i]
    reos, left, left_s = [], 0, 0.0
    for a in range(len(rests) - 1):
        i, j = rests[a].end, rests[a + 1].start
        seconds = float(rec.t[j] - rec.t[i]) if j > i else 0.0
        if seconds <= MAX_REORIENTATION_S:
            reos.append(Reorientation(a, a + 1, i, j, seconds, _mean_temperature(rec, i, j)))
        else:
            left += 1
            left_s += seconds
    return Evidence(rec, correction, rests, pieces, reos, left, left_s, noise, accel)


def _rest(rec: Recording, rate: np.ndarray, corrected_accel: np.ndarray | None, accel: AccelCalibration | None,
          colour: np.ndarray, i: int, j: int) -> Rest:
    """The rest over samples [i, j): its corrected rate's mean and standard error, temperature and gravity."""
    g = None
    if corrected_accel is not None:
        g = corrected_accel[i:j].mean(axis=0)
    elif rec.accel is not None:
        raw = rec.accel[i:j].mean(axis=0)
        g = apply_model(accel.vector, raw[None])[0] if accel is not None else raw
    edge = max(int(EDGE_S * rec.fs), 1)
    first, last = rate[i:min(i + edge, j)], rate[max(j - edge, i):j]
    return Rest(i, j, float(rec.t[(i + j) // 2]), rate[i:j].mean(axis=0), _se(rate[i:j], colour),
                _mean_temperature(rec, i, j), g, (first.mean(axis=0), last.mean(axis=0)), (_se(first, colour), _se(last, colour)))


def _se(rate: np.ndarray, colour: np.ndarray) -> np.ndarray:
    """The standard error of the mean of ``rate`` (n, 3) whose noise is coloured by ``colour``."""
    return np.maximum(rate.std(axis=0) * np.sqrt(colour / len(rate)), SE_FLOOR_DPS)


def _accelerometer(rec: Recording, stills: list) -> AccelCalibration | None:
    """For a correction without the accelerometer's: one fitted on the recording's rests (a study day rests in many
    orientations), else None (the raw readings' directions are used)."""
    if rec.accel is None:
        return None
    try:
        return calibrate_accelerometer(rec, stills)
    except AccelCalibrationError:
        return None
