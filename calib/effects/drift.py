"""Slow changes of the zero-rate output: a drift (in time or with temperature), a temperature ramp, and a
wandering bias (a Gauss-Markov bias instability)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

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

TEMP_RESOLUTION_C = 1.0 / 256.0  # temperature channel step (256 LSB/degC, a common IMU temperature sensor)


TAU_RANGE_S = (5.0, 40.0)  # drawn time constants of a concealed bias instability


def warmup_temperature(t: np.ndarray | float, temp0_c: float, rise_c: float, tau_s: float) -> np.ndarray:
    """Sensor temperature T(t) = T0 + rise * (1 - exp(-t / tau)) (degC) of a device warming up, t in s."""
    return temp0_c + rise_c * -np.expm1(-np.asarray(t, dtype=float) / tau_s)


def _temperature_channel(out: SensorOutput, temp0_c: float, rise_c: float, tau_s: float) -> SensorOutput:
    t = out.t_true if out.t_true is not None else out.t
    temp = warmup_temperature(t, temp0_c, rise_c, tau_s)
    return replace(out, temp=np.round(temp / TEMP_RESOLUTION_C) * TEMP_RESOLUTION_C)


@register_effect
@dataclass(frozen=True)
class BiasDrift(Effect):
    """Bias drift over time, and against temperature when a temperature model is given.

    Model (per axis, deg/s of true rate; t true time in s since the first sample):

        g = K m + b + d t                                   (time drift; d = ``rate_dps_per_s``)
        g = K m + b + d t + c (T(t) - T0)                   (with ``temp_coeff_dps_per_c`` = c)
        T(t) = T0 + rise (1 - exp(-t / tau))                (warm-up; T0 = ``temp0_c``)

    With a temperature model the recording carries the temperature channel T (degC, quantised to
    1/256 degC); the bias then follows b(T) = b + c (T - T0) with T0 = the first sample's
    temperature. CLI value: ``D`` or ``DX,DY,DZ`` (deg/s per s), optionally followed by
    ``:C`` or ``:CX,CY,CZ`` (deg/s per degC) ``:RISE`` (degC) ``[:TAU]`` (s, default 120), e.g.
    ``bias_drift=0.002`` or ``bias_drift=0:0.03:6:90``.
    """

    name: ClassVar[str] = "bias_drift"
    usage: ClassVar[str] = "RATE or RX,RY,RZ (deg/s per s)[:C or CX,CY,CZ (deg/s per degC):RISE (degC)[:TAU (s)]]"
    spec: ClassVar[EffectSpec] = EffectSpec(
        rank=0,
        equation="g = K m + b + d t; with temperature: g = K m + b + d t + c (T - T0), T(t) = T0 + rise (1 - exp(-t/tau))",
        parameters="d (deg/s per s), c (deg/s per degC), rise (degC), tau (s)",
        drawn=MagnitudeRange(
            0.02, 0.2, "deg/s", "largest bias change over the recording (time or temperature)",
            "zero-rate output vs temperature 0.01-0.05 (deg/s)/degC (LSM6DS3, LSM9DS1, ICM-20948 class) "
            "over a warm-up of 1.5-5 degC in the recording (power-on self-heating, skin contact)",
        ),
        reveal="rest the device longer, or several times spread over a longer recording",
        diagnosis_model="g = g0 + d t  (with a temperature channel: g0 + c (T − T0))",
        diagnosis_parameters="d (deg/s per s) or c (deg/s per °C)",
        typical=0.06,  # zero-rate change over a recording (0.01-0.05 (deg/s)/degC, a few degC)
        typical_text="0.06 deg/s over the recording",
        distinguish="a longer recording with several rests (a drift keeps its direction, a wander does not)",
        model_params={"bias_drift": ("d_x", "d_y", "d_z"), "bias_drift_temp": ("c_x", "c_y", "c_z")},
    )
    rate_dps_per_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    temp_coeff_dps_per_c: np.ndarray | None = None
    temp_rise_c: float = 0.0
    temp_tau_s: float = 120.0
    temp0_c: float = 25.0

    @classmethod
    def draw(cls, rng: np.random.Generator, ctx: DrawContext) -> tuple[BiasDrift, float]:
        mag = log_uniform(rng, cls.spec.drawn.low, cls.spec.drawn.high)
        change = spread(rng, mag)
        if ctx.temperature is None:
            return cls(change / ctx.duration_s), mag
        temp0, rise, tau = ctx.temperature
        d_temp = warmup_temperature(ctx.duration_s, 0.0, rise, tau)
        return cls(np.zeros(3), change / d_temp, rise, tau, temp0), mag
    def __post_init__(self) -> None:
        object.__setattr__(self, "rate_dps_per_s", vec3(self.rate_dps_per_s, "BiasDrift.rate_dps_per_s"))
        if self.temp_coeff_dps_per_c is not None:
            object.__setattr__(self, "temp_coeff_dps_per_c", vec3(self.temp_coeff_dps_per_c, "BiasDrift.temp_coeff_dps_per_c"))
        rise = float(self.temp_rise_c)
        if not np.isfinite(rise):
            raise SimulationConfigError(f"BiasDrift.temp_rise_c must be a finite number of degC; got {self.temp_rise_c!r}")
        object.__setattr__(self, "temp_rise_c", rise)
        object.__setattr__(self, "temp_tau_s", positive(self.temp_tau_s, "BiasDrift.temp_tau_s"))
        object.__setattr__(self, "temp0_c", float(self.temp0_c))

    @classmethod
    def from_text(cls, value: str) -> BiasDrift:
        groups = value.split(":")
        if len(groups) not in (1, 3, 4):
            raise usage_error(cls, value)
        d = one_or_three(numbers_of(groups[0], cls), cls, value)
        if len(groups) == 1:
            return cls(d)
        c = one_or_three(numbers_of(groups[1], cls), cls, value)
        rest = [numbers_of(g, cls) for g in groups[2:]]
        if any(len(r) != 1 for r in rest):
            raise usage_error(cls, value)
        return cls(d, c, rest[0][0], *(r[0] for r in rest[1:]))

    @property
    def has_temperature(self) -> bool:
        return self.temp_coeff_dps_per_c is not None

    def temperature(self, t: np.ndarray) -> np.ndarray:
        """T(t) in degC for true times t (s) since the first sample."""
        return warmup_temperature(t, self.temp0_c, self.temp_rise_c, self.temp_tau_s)

    def bias_change(self, t: np.ndarray) -> np.ndarray:
        """The bias added at true times t (n,), (n, 3) deg/s of true rate."""
        t = np.asarray(t, dtype=float)
        db = np.outer(t, self.rate_dps_per_s)
        if self.temp_coeff_dps_per_c is not None:
            db += np.outer(self.temperature(t) - self.temp0_c, self.temp_coeff_dps_per_c)
        return db

    def on_sensor(self, m: np.ndarray, ctx: SensorContext, rng: np.random.Generator) -> np.ndarray:
        # m = (g - b(t)) / k: the extra bias enters in true-rate units, like b.
        return m - self.bias_change(ctx.t - ctx.t[0]) / ctx.k

    def on_output(self, out: SensorOutput, rng: np.random.Generator) -> SensorOutput:
        if not self.has_temperature:
            return out
        return _temperature_channel(out, self.temp0_c, self.temp_rise_c, self.temp_tau_s)

    def to_dict(self) -> dict[str, Any]:
        d = super().to_dict()
        if not self.has_temperature:
            for key in ("temp_coeff_dps_per_c", "temp_rise_c", "temp_tau_s", "temp0_c"):
                d.pop(key)
        return d


@register_effect
@dataclass(frozen=True)
class TemperatureRamp(Effect):
    """A temperature channel only (no effect on the gyro): T(t) = T0 + rise (1 - exp(-t / tau)), degC.

    For recordings that carry a temperature whatever the sensor does. CLI value: ``RISE[,TAU[,T0]]``.
    """

    name: ClassVar[str] = "temperature"
    usage: ClassVar[str] = "RISE[,TAU[,T0]] (degC, s, degC)"
    rise_c: float = 0.0
    tau_s: float = 120.0
    temp0_c: float = 25.0

    def __post_init__(self) -> None:
        if not np.isfinite(float(self.rise_c)):
            raise SimulationConfigError(f"TemperatureRamp.rise_c must be a finite number; got {self.rise_c!r}")
        object.__setattr__(self, "rise_c", float(self.rise_c))
        object.__setattr__(self, "tau_s", positive(self.tau_s, "TemperatureRamp.tau_s"))
        object.__setattr__(self, "temp0_c", float(self.temp0_c))

    def on_output(self, out: SensorOutput, rng: np.random.Generator) -> SensorOutput:
        return _temperature_channel(out, self.temp0_c, self.rise_c, self.tau_s)


@register_effect
@dataclass(frozen=True, eq=False)
class BiasInstability(Effect):
    """Non-white bias noise: a first-order Gauss-Markov bias per axis.

    Model: g = K m + b + x(t), with x (deg/s of true rate) independent per axis,
    x_0 ~ N(0, sigma^2), x_{i+1} = phi_i x_i + sigma sqrt(1 - phi_i^2) w_i, phi_i = exp(-(t_{i+1} - t_i) / tau),
    w_i ~ N(0, 1) (the sampled form of dx = -x / tau dt + sigma sqrt(2 / tau) dW; stationary std sigma,
    autocorrelation sigma^2 exp(-|dt| / tau)). Its Allan deviation peaks at about 0.62 sigma at an
    averaging time of about 1.9 tau, which is the "bias instability" a datasheet or Allan analysis
    would quote. ``sigma_dps`` (deg/s), ``tau_s`` (s). CLI value: ``SIGMA[,TAU]`` (default tau 30 s).
    """

    name: ClassVar[str] = "bias_instability"
    usage: ClassVar[str] = "SIGMA[,TAU] (deg/s, s)"
    spec: ClassVar[EffectSpec] = EffectSpec(
        rank=9,
        equation="g = K m + b + x(t), x_{i+1} = phi x_i + sigma sqrt(1 - phi^2) w_i, phi = exp(-dt/tau)",
        parameters="sigma (deg/s), tau (s)",
        drawn=MagnitudeRange(
            0.005, 0.02, "deg/s", "stationary std sigma of the Gauss-Markov bias (tau 5-40 s)",
            "in-run bias instability 10-40 deg/h (Allan deviation peak 0.62 sigma) of consumer MEMS; "
            "static poses of the real imucal recording differ by 0.015 deg/s",
            drawn_as=f"sigma 0.005-0.02 deg/s, tau {TAU_RANGE_S[0]:g}-{TAU_RANGE_S[1]:g} s",
        ),
        reveal="rest the device longer (the wander shows over tens of seconds of rest)",
        diagnosis_model="g = g0 + x(t), x Gauss-Markov (σ, τ): block covariance σ² exp(−|Δt|/τ), kriged through the turns",
        diagnosis_parameters="σ, τ",
        typical=0.009,  # deg/s: 20 deg/h bias instability (Allan deviation floor 0.62 sigma)
        typical_text="a 0.009 deg/s wander with a 20 s time constant (20 deg/h bias instability)",
        typical_extra={"tau_s": 20.0},
        distinguish="a longer recording with several rests (a wander changes direction, a drift does not)",
    )
    sigma_dps: float = 0.0
    tau_s: float = 30.0

    @classmethod
    def draw(cls, rng: np.random.Generator, ctx: DrawContext) -> tuple[BiasInstability, float]:
        mag = log_uniform(rng, cls.spec.drawn.low, cls.spec.drawn.high)
        return cls(mag, rng.uniform(*TAU_RANGE_S)), mag
    def __post_init__(self) -> None:
        object.__setattr__(self, "sigma_dps", positive(self.sigma_dps, "BiasInstability.sigma_dps", allow_zero=True))
        object.__setattr__(self, "tau_s", positive(self.tau_s, "BiasInstability.tau_s"))

    @classmethod
    def from_text(cls, value: str) -> BiasInstability:
        v = numbers_of(value, cls)
        if len(v) not in (1, 2):
            raise usage_error(cls, value)
        return cls(*v)

    def path(self, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """A realisation x (n, 3) in deg/s at the true times t (n,)."""
        t = np.asarray(t, dtype=float)
        phi = np.exp(-np.diff(t) / self.tau_s)
        drive = rng.standard_normal((t.size, 3))
        drive[0] *= self.sigma_dps
        drive[1:] *= self.sigma_dps * np.sqrt(1.0 - phi * phi)[:, None]
        if phi.size and np.allclose(phi, phi[0], rtol=0, atol=1e-12):
            from scipy.signal import lfilter  # imported here: scipy.signal adds most of a second to start-up

            return lfilter([1.0], [1.0, -phi[0]], drive, axis=0)
        x = drive.copy()
        for i in range(1, t.size):
            x[i] += phi[i - 1] * x[i - 1]
        return x

    def on_sensor(self, m: np.ndarray, ctx: SensorContext, rng: np.random.Generator) -> np.ndarray:
        return m - self.path(ctx.t, rng) / ctx.k
