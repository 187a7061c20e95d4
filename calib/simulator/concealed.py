"""Concealed-effect recordings: a physical effect drawn at random, hidden in a simulated recording.

``draw_concealed(seed, effect, ...)`` draws one effect of the catalogue (``EFFECT_NAMES``) and its
magnitude, simulates the protocol with it and returns the recording with the truth kept apart:
the recording carries nothing that names the effect (same metadata, same channels whatever was
drawn: every case states a gyro range, +-2000 deg/s unless saturation was drawn), so a diagnosis
given only the recording must find the effect from the data. ``effect=None``
gives a null case (no effect) for false-positive checks; the same seed gives the same sensor, motion
and noise with or without the effect.

Each effect draws its own magnitude (``Effect.draw``) in its ``EffectSpec.drawn`` range, gathered in
``RANGES`` (log-uniform between the bounds, random signs, per axis a random share of the largest
component), chosen from the datasheet classes of consumer MEMS
gyroscopes in wearables (InvenSense MPU-6050/MPU-9250/ICM-20948, ST LSM6DS3/LSM9DS1, Bosch BMI160)
and from the real recordings in shared/data/real: large enough to change a calibration, never beyond
what such parts show. ``RANGES[name].why`` says where each range comes from.

Units: rates deg/s, times s, accelerometer g, angles deg, temperature degC.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from calib.effects import (
    CATALOGUE,
    EFFECTS,
    BiasDrift,
    DrawContext,
    Effect,
    MagnitudeRange,
    SimulationConfigError,
    TemperatureRamp,
    catalogue_specs,
)
from calib.effects.spec import log_uniform
from calib.recording import Recording
from calib.simulator import ProtocolScript, Truth, extended_protocol_script, paper_protocol_script, script_duration_s, simulate

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
DEFAULT_FULL_SCALE_DPS = 2000.0  # the range stated when no saturation is drawn (never reached)
HOST_LATENCY_S = (0.01, 0.05)  # constant part of the radio link delay to the host
HOST_JITTER_S = 0.003  # scale of the per-sample delay jitter


# Each catalogue effect's drawn magnitude range (its ``EffectSpec.drawn``).
RANGES: dict[str, MagnitudeRange] = {name: spec.drawn for name, spec in catalogue_specs().items()}

TEMP_RECORDING_RISE_C = (1.5, 5.0)  # temperature change over the recording
TEMP_TAU_S = (30.0, 120.0)
TEMP0_C = (20.0, 32.0)


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
        noise = log_uniform(np.random.default_rng(ss_noise), *NOISE_RANGE_DPS)
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
        chosen, magnitude = EFFECTS[effect].draw(mag_rng, DrawContext(len(script.turns), duration, peak, temp))
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
