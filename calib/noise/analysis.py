"""Noise from a long rest: each gyroscope and accelerometer axis's Allan deviation and the noise parameters read
from it (``calib.noise.terms``), as one ``NoiseReport``.

Units follow the readings: the gyroscope's N in (deg/s)/sqrt(Hz) (= deg/sqrt(s), its angle random walk), B in
deg/s, K in (deg/s)/sqrt(s) (its rate random walk); the accelerometer's in g/sqrt(Hz), g and g/sqrt(s). The report
also gives the figures datasheets use (deg/sqrt(h), deg/h, deg/h/sqrt(h)).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calib.errors import Refusal
from calib.noise.allan import ALPHAS, MAX_FRACTION, MIN_M, MIN_POINTS, AllanCurve, allan_deviation, octave_factors, with_bands
from calib.noise.terms import RANDOM_WALK, WHITE, Reading, TermFit, fit_terms, read_floor, read_slope
from calib.recording import Recording

MOVE_RATE_DPS = 2.0  # a second whose mean rate is this far from the rest's median moved (a hand turns at tens of deg/s)
MOVE_ACCEL_G = 0.05  # a second whose mean specific force is this far from the rest's median was tilted or carried
AXES = "xyz"


@dataclass(frozen=True)
class AxisNoise:
    """One axis's curve, the fitted terms and the three readings (noise density, bias instability, random walk)."""

    axis: str
    curve: AllanCurve
    fit: TermFit  # the terms fitted to the curve (the readings' units)
    density: Reading
    bias_instability: Reading
    random_walk: Reading

    def to_json(self) -> dict[str, Any]:
        """The axis as JSON: readings, fitted terms and the curve with its bands."""
        c = self.curve
        return {"axis": self.axis, "noise_density": self.density.to_json(),
                "bias_instability": self.bias_instability.to_json(), "random_walk": self.random_walk.to_json(),
                "fit": self.fit.to_json(),
                "curve": {"tau_s": c.tau_s.tolist(), "adev": c.adev.tolist(), "lo95": c.lo95.tolist(), "hi95": c.hi95.tolist(),
                          "edf": c.edf.tolist(), "fit_adev": self.fit.adev(c.tau_s).tolist()}}


@dataclass(frozen=True)
class NoiseReport:
    """A rest's noise: per gyroscope axis and (when recorded) per accelerometer axis."""

    source: str | None
    sample_rate_hz: float
    duration_s: float
    gyro: tuple[AxisNoise, ...]
    accel: tuple[AxisNoise, ...] | None
    lost_samples: int = 0  # samples missing from the time stamps (or the counter); the curve reads the rest as evenly spaced
    units: dict[str, dict[str, str]] = field(default_factory=lambda: {
        "gyro": {"noise_density": "(deg/s)/sqrt(Hz)", "bias_instability": "deg/s", "random_walk": "(deg/s)/sqrt(s)"},
        "accel": {"noise_density": "g/sqrt(Hz)", "bias_instability": "g", "random_walk": "g/sqrt(s)"}})

    def to_json(self) -> dict[str, Any]:
        """The report as JSON (``gyrocal noise --json``, the service's noise upload)."""
        return {"source": self.source, "sample_rate_hz": self.sample_rate_hz, "duration_s": self.duration_s,
                "lost_samples": self.lost_samples, "units": self.units, "gyro": [a.to_json() for a in self.gyro],
                "accel": None if self.accel is None else [a.to_json() for a in self.accel]}

    def text(self) -> str:
        """The readings as a table a person reads (with the datasheet units)."""
        lines = [f"{self.source or 'recording'}: {self.duration_s:.0f} s at rest, {self.sample_rate_hz:g} Hz",
                 "gyroscope     noise density (ARW)               bias instability            rate random walk"]
        for a in self.gyro:
            lines.append(f"  {a.axis}  " + "  ".join((
                _fmt(a.density, 60.0, "deg/sqrt(h)"), _fmt(a.bias_instability, 3600.0, "deg/h"),
                _fmt(a.random_walk, 3600.0 * 60.0, "deg/h/sqrt(h)"))))
        if self.accel is not None:
            lines.append("accelerometer noise density (VRW)               bias instability            accel. random walk")
            for a in self.accel:
                lines.append(f"  {a.axis}  " + "  ".join((
                    _fmt(a.density, 1e6, "ug/sqrt(Hz)"), _fmt(a.bias_instability, 1e6, "ug"),
                    _fmt(a.random_walk, 1e6, "ug/sqrt(s)"))))
        lines.append("[low, high] is the 95 % interval; '<' an upper bound where the curve does not show the term; "
                     "τ where each was read")
        if self.lost_samples:
            lines.append(f"{self.lost_samples} samples are missing from the recording: the curve takes the others as evenly "
                         "spaced, which bends it at averaging times near the gaps")
        return "\n".join(lines)


def _fmt(r: Reading, scale: float, unit: str) -> str:
    if r.value is None or r.lo95 is None:
        return f"< {r.hi95 * scale:8.3g} {unit:<13} (τ {r.tau_s:.3g} s)".ljust(34)
    return f"{r.value * scale:8.3g} [{r.lo95 * scale:.3g}, {r.hi95 * scale:.3g}] {unit} (τ {r.tau_s:.3g} s)".ljust(34)


def check_rest(rec: Recording) -> None:
    """Refusal naming when the recording moved or how long a rest it needs; nothing when it is one rest."""
    n_needed = int(np.ceil(MIN_M * 2 ** (MIN_POINTS - 1) / MAX_FRACTION))
    if len(rec) < n_needed:
        raise Refusal(f"{rec.duration_s:.1f} s of rest is too short for an Allan analysis: it needs at least {n_needed} samples "
                      f"({n_needed / rec.fs:.0f} s at {rec.fs:g} Hz), and an hour reads the rate random walk; record the "
                      "device lying still for longer", code="rest_too_short")
    per = max(int(round(rec.fs)), 1)
    for what, data, limit, unit in (("turns", rec.gyro, MOVE_RATE_DPS, "deg/s"), ("is tilted or carried", rec.accel, MOVE_ACCEL_G, "g")):
        if data is None:
            continue
        blocks = data[: len(data) // per * per].reshape(-1, per, 3).mean(axis=1)
        away = np.abs(blocks - np.median(blocks, axis=0)).max(axis=1)
        moved = np.flatnonzero(away > limit)
        if moved.size:
            at = float(rec.t[moved[0] * per] - rec.t[0])
            raise Refusal(f"the device {what} {at:.1f} s into the recording (a second {away[moved[0]]:.3g} {unit} from the "
                          f"rest's median, over {limit:g}; {moved.size} such seconds): the noise is read from one rest. Cut "
                          "the rest out, or record the device lying still", code="not_a_rest")


def _axis(x: np.ndarray, fs: float, m: np.ndarray, axis: str) -> AxisNoise:
    tau = m / fs
    adev = allan_deviation(x, fs, m)
    white = np.tile(np.eye(len(ALPHAS))[0], (m.size, 1))
    curve = with_bands(tau, adev, m, x.size, white)
    for _ in range(2):  # the noise types from the fit, the fit from the bands they give
        fit = fit_terms(curve)
        curve = with_bands(tau, adev, m, x.size, fit.type_shares(tau))
    fit = fit_terms(curve)
    return AxisNoise(axis, curve, fit, read_slope(curve, fit, WHITE, "noise_density"), read_floor(curve, fit),
                     read_slope(curve, fit, RANDOM_WALK, "random_walk"))


def noise(rec: Recording, progress: Callable[[int], None] | None = None) -> NoiseReport:
    """The noise of a recording of one rest (Refusal when it moves or is too short): each axis's overlapping Allan
    deviation with 95 % bands and its noise density, bias instability and random walk. ``progress`` is called with 1
    after each axis."""
    check_rest(rec)
    m = octave_factors(len(rec))
    fs = rec.fs

    def axes(data: np.ndarray) -> tuple[AxisNoise, ...]:
        out = []
        for i, name in enumerate(AXES):
            out.append(_axis(data[:, i], fs, m, name))
            if progress is not None:
                progress(1)
        return tuple(out)

    gyro = axes(rec.gyro)
    accel = None if rec.accel is None else axes(rec.accel)
    from calib.diagnosis.timebase import analyse_timebase  # the one count of lost samples (counter, or device stamps)

    return NoiseReport(rec.meta.source, float(fs), float(rec.duration_s), gyro, accel, analyse_timebase(rec).lost)
