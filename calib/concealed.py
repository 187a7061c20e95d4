"""Concealed-effect recordings: a physical effect drawn at random, hidden in a simulated recording.

``draw_concealed(seed, effect, ...)`` draws one effect of the catalogue (``EFFECT_NAMES``) and its
magnitude, simulates the protocol with it and returns the recording with the truth kept apart:
the recording carries nothing that names the effect (same metadata, same channels whatever was
drawn: every case states a gyro range, +-2000 deg/s unless saturation was drawn), so a diagnosis
given only the recording must find the effect from the data. ``effect=None``
gives a null case (no effect) for false-positive checks; the same seed gives the same sensor, motion
and noise with or without the effect.

Magnitudes are drawn in the ranges of ``RANGES`` (log-uniform between the bounds, random signs, per
axis a random share of the largest component), chosen from the datasheet classes of consumer MEMS
gyroscopes in wearables (InvenSense MPU-6050/MPU-9250/ICM-20948, ST LSM6DS3/LSM9DS1, Bosch BMI160)
and from the real recordings in shared/data/real: large enough to change a calibration, never beyond
what such parts show. ``RANGES[name].why`` says where each range comes from.

Units: rates deg/s, times s, accelerometer g, angles deg, temperature degC.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from .effects import (
    CATALOGUE,
    AxisMisalignment,
    BiasDrift,
    BiasInstability,
    ClockError,
    Effect,
    GSensitivity,
    PlacementError,
    SampleLoss,
    Saturation,
    ScaleAsymmetry,
    ScaleNonlinearity,
    SimulationConfigError,
    TemperatureRamp,
    warmup_temperature,
)
from .recording import Recording
from .simulator import (
    ProtocolScript,
    Truth,
    extended_protocol_script,
    paper_protocol_script,
    script_duration_s,
    simulate,
)

__all__ = [
    "EFFECT_NAMES",
    "PROTOCOLS",
    "RANGES",
    "ConcealedCase",
    "MagnitudeRange",
    "draw_concealed",
    "protocol_script",
    "strip_channels",
]

EFFECT_NAMES: tuple[str, ...] = CATALOGUE
PROTOCOLS: tuple[str, ...] = ("paper", "extended")
FS_HZ = 104.0
NOISE_RANGE_DPS = (0.02, 0.1)  # white reading noise at 104 Hz: 0.004-0.015 (deg/s)/sqrt(Hz) over ~50 Hz
STANDARD_FULL_SCALES_DPS = (125.0, 245.0, 250.0, 500.0, 1000.0)  # gyro ranges of consumer parts
DEFAULT_FULL_SCALE_DPS = 2000.0  # the range stated when no saturation is drawn (never reached)
HOST_LATENCY_S = (0.01, 0.05)  # constant part of the radio link delay to the host
HOST_JITTER_S = 0.003  # scale of the per-sample delay jitter


@dataclass(frozen=True)
class MagnitudeRange:
    """The drawn range of an effect's magnitude: [low, high] in ``unit``; ``what`` the magnitude is."""

    low: float
    high: float
    unit: str
    what: str
    why: str


RANGES: dict[str, MagnitudeRange] = {
    "bias_drift": MagnitudeRange(
        0.02, 0.2, "deg/s", "largest bias change over the recording (time or temperature)",
        "zero-rate output vs temperature 0.01-0.05 (deg/s)/degC (LSM6DS3, LSM9DS1, ICM-20948 class) "
        "over a warm-up of 1.5-5 degC in the recording (power-on self-heating, skin contact)",
    ),
    "axis_misalignment": MagnitudeRange(
        0.003, 0.02, "", "largest off-diagonal entry of K",
        "cross-axis sensitivity +-1-2 % (MPU-6050, ICM-20948, LSM6DS3 datasheets); 0.0097 in the "
        "real imucal recording",
    ),
    "g_sensitivity": MagnitudeRange(
        0.02, 0.15, "(deg/s)/g", "largest entry of G",
        "linear-acceleration sensitivity 0.1 (deg/s)/g typical (MPU-6050/MPU-9250 datasheets); "
        "0.006 (deg/s)/g in the real imucal recording",
    ),
    "scale_asymmetry": MagnitudeRange(
        0.002, 0.01, "", "largest relative difference s of the scale factor between directions",
        "within the sensitivity tolerance (+-1-3 %) and nonlinearity budget of consumer parts",
    ),
    "scale_nonlinearity": MagnitudeRange(
        0.002, 0.01, "", "largest relative scale change n at 1000 deg/s",
        "nonlinearity +-0.1-0.5 % FS at +-2000 deg/s (ICM-20948 0.1 %, MPU-6050 0.2 %, BMI160 0.1 % "
        "class); n = 4 NL r0 / FS",
    ),
    "saturation": MagnitudeRange(
        50.0, 1000.0, "deg/s", "full scale",
        "the +-125 / 245 / 250 / 500 / 1000 deg/s ranges of consumer parts, one below the "
        "recording's peak reading (hand turns reach 110-500 deg/s); 0.7-0.9 of the peak if none is",
    ),
    "sample_loss": MagnitudeRange(
        0.002, 0.03, "", "expected fraction of samples lost",
        "Bluetooth Low Energy links of wearables lose 0.1-3 % of packets of 1-12 samples",
    ),
    "placement_error": MagnitudeRange(
        0.3, 2.0, "deg", "std of each component of the placement rotation per turn",
        "a device turned by hand and put back down by eye: tilt and heading off by 0.3-2 deg",
    ),
    "clock_error": MagnitudeRange(
        0.003, 0.03, "", "|e|, fraction the device clock runs fast (+) or slow (-)",
        "internal oscillators of consumer IMUs set the output data rate to +-1-3 %",
    ),
    "bias_instability": MagnitudeRange(
        0.005, 0.02, "deg/s", "stationary std sigma of the Gauss-Markov bias (tau 5-40 s)",
        "in-run bias instability 10-40 deg/h (Allan deviation peak 0.62 sigma) of consumer MEMS; "
        "static poses of the real imucal recording differ by 0.015 deg/s",
    ),
}

BIAS_INSTABILITY_TAU_S = (5.0, 40.0)
TEMP_RECORDING_RISE_C = (1.5, 5.0)  # temperature change over the recording
TEMP_TAU_S = (30.0, 120.0)
TEMP0_C = (20.0, 32.0)
LOSS_BURST = (1, 12)


@dataclass(frozen=True, eq=False)
class ConcealedCase:
    """One concealed case: the recording the tool gets, and the truth it must find.

    ``effect_name``: the catalogue name, None for a null case. ``magnitude``: see ``RANGES`` (0 for
    a null case). ``effect``: the effect as simulated (its ``to_dict()`` is in the truth).
    ``host_t``: the time each row reached the host (s, true clock plus link delay), the outside
    clock that reveals a clock error.
    """

    recording: Recording
    truth: Truth
    effect_name: str | None
    magnitude: float
    effect: Effect | None
    host_t: np.ndarray
    seed: int
    protocol: str
    noise_dps: float
    with_accel: bool
    with_seq: bool
    with_temp: bool

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description of the case and its truth."""
        return {
            "seed": self.seed,
            "protocol": self.protocol,
            "effect_name": self.effect_name,
            "magnitude": self.magnitude,
            "magnitude_unit": RANGES[self.effect_name].unit if self.effect_name else None,
            "noise_dps": self.noise_dps,
            "with_accel": self.with_accel,
            "with_seq": self.with_seq,
            "with_temp": self.with_temp,
            "truth": self.truth.to_dict(),
        }


def protocol_script(name: str, rng: np.random.Generator) -> ProtocolScript:
    """The script of protocol ``name`` ("paper": 3 turns; "extended": both ways at two speeds per axis)."""
    if name == "paper":
        return paper_protocol_script(rng)
    if name == "extended":
        return extended_protocol_script(rng)
    raise SimulationConfigError(f"protocol must be one of {', '.join(PROTOCOLS)}; got {name!r}")


def strip_channels(rec: Recording, accel: bool = True, seq: bool = True) -> Recording:
    """The recording without the accelerometer (``accel=False``) and/or the sample counter (``seq=False``)."""
    return replace(rec, accel=rec.accel if accel else None, seq=rec.seq if seq else None)


def _log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(np.exp(rng.uniform(np.log(low), np.log(high))))


def _spread(rng: np.random.Generator, largest: float, shape: tuple[int, ...] = (3,)) -> np.ndarray:
    """Random signs and shares, the largest component exactly ``largest`` in size."""
    u = rng.uniform(-1.0, 1.0, shape)
    return largest * u / np.max(np.abs(u))


def _draw_effect(
    name: str,
    rng: np.random.Generator,
    script: ProtocolScript,
    duration_s: float,
    peak_dps: float,
    temp: tuple[float, float, float] | None,
) -> tuple[Effect, float]:
    """One effect of the catalogue and its magnitude (see ``RANGES``)."""
    r = RANGES[name]
    if name == "saturation":
        below = [fs for fs in STANDARD_FULL_SCALES_DPS if fs * 1.05 < peak_dps]
        fs = float(rng.choice(below)) if below else round(float(rng.uniform(0.7, 0.9) * peak_dps), 1)
        return Saturation(fs, fs / 32768.0), fs  # 16-bit readings
    if name == "sample_loss":
        frac = _log_uniform(rng, r.low, r.high)
        burst = int(rng.integers(LOSS_BURST[0], LOSS_BURST[1] + 1))
        return SampleLoss(prob=1.0 - (1.0 - frac) ** (1.0 / burst), burst=burst), frac
    mag = _log_uniform(rng, r.low, r.high)
    if name == "bias_drift":
        change = _spread(rng, mag)
        if temp is None:
            return BiasDrift(change / duration_s), mag
        temp0, rise, tau = temp
        d_temp = warmup_temperature(duration_s, 0.0, rise, tau)
        return BiasDrift(np.zeros(3), change / d_temp, rise, tau, temp0), mag
    if name == "axis_misalignment":
        return AxisMisalignment(_spread(rng, mag)), mag
    if name == "g_sensitivity":
        return GSensitivity(_spread(rng, mag, (3, 3))), mag
    if name == "scale_asymmetry":
        return ScaleAsymmetry(_spread(rng, mag)), mag
    if name == "scale_nonlinearity":
        return ScaleNonlinearity(_spread(rng, mag)), mag
    if name == "placement_error":
        effect = PlacementError(mag)
        return replace(effect, errors_deg=effect.draw_errors(len(script.turns), rng)), mag
    if name == "clock_error":
        return ClockError(mag * rng.choice([-1.0, 1.0])), mag
    if name == "bias_instability":
        return BiasInstability(mag, rng.uniform(*BIAS_INSTABILITY_TAU_S)), mag
    raise SimulationConfigError(f"no draw for effect {name!r}")  # pragma: no cover - catalogue and draws agree


def draw_concealed(
    seed: int,
    effect: str | None = None,
    protocol: str = "paper",
    with_accel: bool = True,
    with_seq: bool = True,
    noise: float | None = None,
    with_temp: bool = False,
) -> ConcealedCase:
    """A recording with one effect of the catalogue hidden in it, drawn at random (deterministic by seed).

    ``effect``: a name of ``EFFECT_NAMES``, "random" (one drawn uniformly) or None (no effect: a null
    case). ``protocol``: "paper" or "extended". ``with_accel`` / ``with_seq``: keep the accelerometer
    and the sample counter in the recording. ``noise``: white reading noise (deg/s); None draws it
    log-uniform in 0.02-0.1 deg/s. ``with_temp``: the recording carries a temperature channel (a
    warm-up of 1.5-5 degC over the recording) whatever the effect; bias drift then follows the
    temperature instead of time. Sensor parameters k, b are drawn as in the paper (Section 3).
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SimulationConfigError(f"seed must be a whole number >= 0; got {seed!r}")
    seed = int(seed)
    ss_choice, ss_mag, ss_noise, ss_script, ss_host, ss_temp = np.random.SeedSequence([seed, 0x6E7C]).spawn(6)
    if effect == "random":
        effect = str(np.random.default_rng(ss_choice).choice(EFFECT_NAMES))
    if effect is not None and effect not in EFFECT_NAMES:
        raise SimulationConfigError(f"effect must be None, 'random' or one of {', '.join(EFFECT_NAMES)}; got {effect!r}")
    if noise is None:
        noise = _log_uniform(np.random.default_rng(ss_noise), *NOISE_RANGE_DPS)
    script = protocol_script(protocol, np.random.default_rng(ss_script))
    duration = script_duration_s(script)

    temp = None
    if with_temp:
        trng = np.random.default_rng(ss_temp)
        tau = trng.uniform(*TEMP_TAU_S)
        rise = trng.uniform(*TEMP_RECORDING_RISE_C) / -np.expm1(-duration / tau)
        temp = (float(trng.uniform(*TEMP0_C)), float(rise), float(tau))

    rec, truth = simulate(seed, noise=noise, fs=FS_HZ, script=script)
    chosen: Effect | None = None
    magnitude = 0.0
    effects: list[Effect] = []
    if effect is not None:
        peak = float(np.max(np.abs(rec.gyro)))
        # each effect its own stream, so that one seed does not put every effect at the same quantile
        mag_rng = np.random.default_rng(np.random.SeedSequence(ss_mag.entropy, spawn_key=(*ss_mag.spawn_key, EFFECT_NAMES.index(effect))))
        chosen, magnitude = _draw_effect(effect, mag_rng, script, duration, peak, temp)
        effects.append(chosen)
    if temp is not None and not (isinstance(chosen, BiasDrift) and chosen.has_temperature):
        effects.append(TemperatureRamp(temp[1], temp[2], temp[0]))
    if effects:  # same seed: same sensor, motion and noise as the case without them
        rec, truth = simulate(seed, noise=noise, fs=FS_HZ, script=script, effects=effects)
    if rec.meta.gyro_full_scale_dps is None:  # every case states a range, so the metadata tells nothing
        rec = rec.with_meta(gyro_full_scale_dps=DEFAULT_FULL_SCALE_DPS)

    hrng = np.random.default_rng(ss_host)
    t_true = truth.t_true if truth.t_true is not None else rec.t
    host_t = t_true + hrng.uniform(*HOST_LATENCY_S) + np.abs(hrng.normal(0.0, HOST_JITTER_S, t_true.size))
    host_t = np.maximum.accumulate(host_t)  # the link delivers in order: a late sample holds up the next
    rec = replace(strip_channels(rec, accel=with_accel, seq=with_seq), host_t=host_t)
    return ConcealedCase(
        recording=rec,
        truth=truth,
        effect_name=effect,
        magnitude=float(magnitude),
        effect=chosen,
        host_t=host_t,
        seed=seed,
        protocol=protocol,
        noise_dps=float(noise),
        with_accel=bool(with_accel),
        with_seq=bool(with_seq),
        with_temp=bool(with_temp),
    )
