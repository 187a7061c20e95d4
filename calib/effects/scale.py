"""Errors of the scale factor and its range: asymmetry between directions, nonlinearity with rate, saturation."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np

from calib.effects.base import (
    Effect,
    SensorContext,
    SensorOutput,
    SimulationConfigError,
    numbers_of,
    one_or_three,
    positive,
    register_effect,
    usage_error,
    vec3,
)
from calib.effects.spec import DrawContext, EffectSpec, MagnitudeRange, log_uniform, spread

STANDARD_FULL_SCALES_DPS = (125.0, 245.0, 250.0, 500.0, 1000.0)  # gyro ranges of consumer parts


@register_effect
@dataclass(frozen=True, eq=False)
class ScaleAsymmetry(Effect):
    """Different scale factors for positive and negative rates.

    Model (per axis): g = (1 + s sign(g0)) g0 with g0 = K m + b, s = ``asymmetry`` (dimensionless,
    |s| < 0.5). So the scale factor is k (1 + s) for positive true rates and k (1 - s) for negative
    ones, and the zero-rate reading (g = 0) is unchanged. Shows only with turns both ways.
    CLI value: ``S`` or ``SX,SY,SZ``, e.g. ``scale_asymmetry=0.005``.
    """

    name: ClassVar[str] = "scale_asymmetry"
    usage: ClassVar[str] = "S or SX,SY,SZ (fraction)"
    spec: ClassVar[EffectSpec] = EffectSpec(
        rank=3,
        equation="g = (1 + s sign(g0)) g0",
        parameters="s (fraction)",
        drawn=MagnitudeRange(
            0.002, 0.01, "", "largest relative difference s of the scale factor between directions",
            "within the sensitivity tolerance (+-1-3 %) and nonlinearity budget of consumer parts",
        ),
        reveal="turn about each axis both ways (clockwise and counter-clockwise)",
        diagnosis_model="g = (1 + s sign g0) g0",
        diagnosis_parameters="s per axis",
        typical=0.005,
        typical_text="0.5 % between directions",
        distinguish="turns about each axis both ways",
        model_params={"scale_asymmetry": ("s_x", "s_y", "s_z")},
    )
    asymmetry: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @classmethod
    def draw(cls, rng: np.random.Generator, ctx: DrawContext) -> tuple[ScaleAsymmetry, float]:
        mag = log_uniform(rng, cls.spec.drawn.low, cls.spec.drawn.high)
        return cls(spread(rng, mag)), mag
    def __post_init__(self) -> None:
        s = vec3(self.asymmetry, "ScaleAsymmetry.asymmetry")
        if np.any(np.abs(s) >= 0.5):
            raise SimulationConfigError(f"ScaleAsymmetry.asymmetry must be smaller than 0.5 in size; got {self.asymmetry!r}")
        object.__setattr__(self, "asymmetry", s)

    @classmethod
    def from_text(cls, value: str) -> ScaleAsymmetry:
        return cls(one_or_three(numbers_of(value, cls), cls, value))

    def on_sensor(self, m: np.ndarray, ctx: SensorContext, rng: np.random.Generator) -> np.ndarray:
        g = m * ctx.k + ctx.b
        g0 = g / (1.0 + self.asymmetry * np.sign(g))
        return (g0 - ctx.b) / ctx.k


@register_effect
@dataclass(frozen=True, eq=False)
class ScaleNonlinearity(Effect):
    """Scale factor that changes with the rate (odd-symmetric, quadratic in |rate|).

    Model (per axis): g = (1 + n |g0| / r0) g0 with g0 = K m + b, n = ``coeff`` (dimensionless: the
    relative change of the scale factor at |rate| = r0), r0 = ``ref_rate_dps`` (default 1000 deg/s).
    Over a range +-FS this deviates from the best straight line by n FS / (4 r0) of FS (the datasheet
    "nonlinearity, % FS"), so n = 0.004 is 0.2 % FS at +-2000 deg/s. Shows with turns at different
    speeds. CLI value: ``N`` or ``NX,NY,NZ`` optionally ``:R0``, e.g. ``scale_nonlinearity=0.005``.
    """

    name: ClassVar[str] = "scale_nonlinearity"
    usage: ClassVar[str] = "N or NX,NY,NZ (fraction at R0)[:R0 (deg/s, default 1000)]"
    spec: ClassVar[EffectSpec] = EffectSpec(
        rank=4,
        equation="g = (1 + n |g0| / r0) g0, r0 = 1000 deg/s",
        parameters="n (fraction at r0)",
        drawn=MagnitudeRange(
            0.002, 0.01, "", "largest relative scale change n at 1000 deg/s",
            "nonlinearity +-0.1-0.5 % FS at +-2000 deg/s (ICM-20948 0.1 %, MPU-6050 0.2 %, BMI160 0.1 % class); n = 4 NL r0 / FS",
        ),
        reveal="turn about each axis at two clearly different speeds (one slow, one fast turn)",
        diagnosis_model="g = (1 + n |g0| / 1000 deg/s) g0",
        diagnosis_parameters="n per axis",
        typical=0.005,  # relative scale change at 1000 deg/s (0.1-0.5 % FS nonlinearity)
        typical_text="0.5 % at 1000 deg/s",
        distinguish="turns about each axis at two clearly different speeds",
        model_params={"scale_nonlinearity": ("n_x", "n_y", "n_z")},
    )
    coeff: np.ndarray = field(default_factory=lambda: np.zeros(3))
    ref_rate_dps: float = 1000.0

    @classmethod
    def draw(cls, rng: np.random.Generator, ctx: DrawContext) -> tuple[ScaleNonlinearity, float]:
        mag = log_uniform(rng, cls.spec.drawn.low, cls.spec.drawn.high)
        return cls(spread(rng, mag)), mag
    def __post_init__(self) -> None:
        object.__setattr__(self, "coeff", vec3(self.coeff, "ScaleNonlinearity.coeff"))
        object.__setattr__(self, "ref_rate_dps", positive(self.ref_rate_dps, "ScaleNonlinearity.ref_rate_dps"))

    @classmethod
    def from_text(cls, value: str) -> ScaleNonlinearity:
        groups = value.split(":")
        if len(groups) not in (1, 2):
            raise usage_error(cls, value)
        n = one_or_three(numbers_of(groups[0], cls), cls, value)
        if len(groups) == 1:
            return cls(n)
        r0 = numbers_of(groups[1], cls)
        if len(r0) != 1:
            raise usage_error(cls, value)
        return cls(n, r0[0])

    def on_sensor(self, m: np.ndarray, ctx: SensorContext, rng: np.random.Generator) -> np.ndarray:
        g = m * ctx.k + ctx.b
        c = self.coeff / self.ref_rate_dps
        disc = 1.0 + 4.0 * c * np.abs(g)
        if np.any(disc <= 0):
            raise SimulationConfigError("scale_nonlinearity: the rates are too high for so negative a coefficient")
        # |g0| solves |g0| + c |g0|^2 = |g| (stable root)
        g0 = 2.0 * g / (1.0 + np.sqrt(disc))
        return (g0 - ctx.b) / ctx.k


@register_effect
@dataclass(frozen=True)
class Saturation(Effect):
    """Gyro range: m_out = clip(q(m), -FS, FS), q rounding to ``resolution_dps`` (if given).

    FS = ``full_scale_dps`` (deg/s of reading); the recording's metadata states it
    (``RecordingMeta.gyro_full_scale_dps``) and the true stages that clip are flagged "saturated".
    A clipped sample only bounds the reading: |m| >= FS. CLI value: ``FULL_SCALE[,RESOLUTION]`` (deg/s).
    """

    name: ClassVar[str] = "saturation"
    usage: ClassVar[str] = "FULL_SCALE[,RESOLUTION] (deg/s)"
    spec: ClassVar[EffectSpec] = EffectSpec(
        rank=5,
        equation="m_out = clip(m, -FS, FS), FS in the metadata",
        parameters="FS, resolution (deg/s)",
        drawn=MagnitudeRange(
            50.0, 1000.0, "deg/s", "full scale",
            "the +-125 / 245 / 250 / 500 / 1000 deg/s ranges of consumer parts, one below the "
            "recording's peak reading (hand turns reach 110-500 deg/s); 0.7-0.9 of the peak if none is",
            drawn_as="125/245/250/500/1000 deg/s below the peak reading (else 0.7-0.9 of the peak)",
        ),
        reveal="the readings never reached the gyro's full scale",
        diagnosis_model="clipped turns' closures left free; plateaus rebuilt as parabolic caps",
        diagnosis_parameters="full scale, hidden rotation",
    )
    full_scale_dps: float = 2000.0
    resolution_dps: float | None = None

    @classmethod
    def draw(cls, rng: np.random.Generator, ctx: DrawContext) -> tuple[Saturation, float]:
        below = [fs for fs in STANDARD_FULL_SCALES_DPS if fs * 1.05 < ctx.peak_dps]
        fs = float(rng.choice(below)) if below else round(float(rng.uniform(0.7, 0.9) * ctx.peak_dps), 1)
        return cls(fs, fs / 32768.0), fs  # 16-bit readings
    def __post_init__(self) -> None:
        if not (np.isfinite(self.full_scale_dps) and self.full_scale_dps > 0):
            raise SimulationConfigError(f"full_scale_dps must be a positive number of deg/s; got {self.full_scale_dps!r}")
        if self.resolution_dps is not None and not (np.isfinite(self.resolution_dps) and self.resolution_dps > 0):
            raise SimulationConfigError(f"resolution_dps must be a positive number of deg/s; got {self.resolution_dps!r}")
        object.__setattr__(self, "full_scale_dps", float(self.full_scale_dps))
        if self.resolution_dps is not None:
            object.__setattr__(self, "resolution_dps", float(self.resolution_dps))

    def on_output(self, out: SensorOutput, rng: np.random.Generator) -> SensorOutput:
        gyro = out.gyro
        if self.resolution_dps is not None:
            gyro = np.round(gyro / self.resolution_dps) * self.resolution_dps
        gyro = np.clip(gyro, -self.full_scale_dps, self.full_scale_dps)
        return replace(out, gyro=gyro, full_scale_dps=self.full_scale_dps)
