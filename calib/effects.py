"""Physical effects the protocol simulator can switch on, and the pipeline stages they act on.

The simulator (``calib.simulator``) produces a recording in three stages; an ``Effect`` may act on
any of them by overriding the matching hook (the default hooks change nothing):

1. ``on_trajectory(traj, rng) -> Trajectory`` — the true motion and time base, before the sensor:
   placement error (the pose after a turn), clock error (true sample times ``t`` differ from the
   stamps ``t_device`` the device reports).
2. ``on_sensor(m, ctx, rng) -> m`` — the sensor model from true rate to reading. ``m`` enters as the
   ideal reading (g - b) / k of eq. (1), before white noise; ``ctx`` gives the true rate, the specific
   force, the true times and the parameters. Misalignment, g-sensitivity, scale asymmetry and
   nonlinearity, bias drift and bias instability belong here.
3. ``on_output(out, rng) -> SensorOutput`` — what leaves the device, after white noise: saturation,
   quantisation, lost samples (drop rows with ``SensorOutput.keep``; ``seq`` then shows the gaps),
   the temperature channel.

Within a stage, effects run in the order given. Each effect draws from its own random generator,
so switching one effect on does not change the motion, the noise or another effect's draws.
``to_dict()`` (the dataclass fields plus ``name``) is what ``Truth.to_dict()["effects"]`` lists.

The catalogue (``CATALOGUE``), each model written as the true rate g (deg/s, sensor axes) in terms of
the reading m (deg/s), exactly as the simulator generates it (before white noise). Notation:
K = diag(k), b in deg/s of true rate, g0 = K m + b (the rate the paper's model eq. (1) gives),
a = specific force (g, sensor axes; +1 along the upward axis at rest), t = time since the first
sample (s), products and |.| element-wise per axis:

- bias_drift          g = K m + b + d t                        [+ c (T(t) - T0) with a temperature channel]
- axis_misalignment   g = (diag(k) + U) m + b,  U upper-triangular (K_xy, K_xz, K_yz)
- g_sensitivity       g = K (m - G a) + b,      G (3, 3) in (deg/s)/g
- scale_asymmetry     g = (1 + s sign(g0)) g0
- scale_nonlinearity  g = (1 + n |g0| / r0) g0,  r0 = 1000 deg/s
- saturation          m_out = clip(m, -FS, FS) (after optional quantisation)
- sample_loss         rows missing; t and seq of the kept rows unchanged, so both show the gap
- placement_error     the pose after turn j is off by the world-frame rotation Exp(e_j)
- clock_error         t_device = (1 + e) t_true
- bias_instability    g = K m + b + x(t),  x first-order Gauss-Markov (sigma, tau)

Each class docstring gives the exact equation, parameters, units and the CLI value syntax. The
equations hold exactly for one sensor-stage effect at a time; several compose in the order given
(each transforms the readings the previous one produced).

Adding an effect: subclass ``Effect`` as a frozen dataclass with a ``name``, override the hooks it
needs, decorate it with ``@register_effect`` so that ``parse_effect`` (the CLI's ``--effect
NAME=VALUE``) knows it, and give it ``from_text`` if its CLI value is not just its numeric fields.

Units: rates deg/s, times s, specific force g, angles deg, temperature degC.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any, ClassVar

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import GyrocalError
from .stage import Stage


class SimulationConfigError(GyrocalError, ValueError):
    """A simulator setting is invalid; the message says which one and what is accepted."""


@dataclass(frozen=True, eq=False)
class Trajectory:
    """The true motion, sampled: what the sensor is exposed to.

    ``rate[i]`` is the true body rate over [t_i, t_{i+1}) (deg/s, sensor axes), exactly
    Log(attitude[i]^-1 attitude[i+1]) / (t_{i+1} - t_i) on the true clock (dt = 1 / fs unless a clock
    effect changes the true sample times); ``attitude`` holds the n + 1 body-to-start-frame poses at
    the sample instants; ``accel[i]`` the true specific force at t_i in sensor axes (g; +1 along the
    upward axis at rest). ``t`` are the true sample times (s), ``t_device`` the stamps the device
    reports (s; equal to ``t`` unless a clock effect changes one of them).
    """

    t: np.ndarray
    t_device: np.ndarray
    rate: np.ndarray
    attitude: Rotation
    accel: np.ndarray
    stages: tuple[Stage, ...]
    segment_axes: tuple[np.ndarray | None, ...]  # true unit axis of each turn/motion stage, None for stills
    fs: float

    @property
    def n(self) -> int:
        return int(self.t.size)

    @property
    def dt(self) -> float:
        """Nominal sample interval (s)."""
        return 1.0 / self.fs


@dataclass(frozen=True, eq=False)
class SensorContext:
    """What a sensor-stage effect may use: true rate (deg/s), specific force (g), times (s), eq. (1) parameters."""

    t: np.ndarray  # (n,) true sample times, s
    rate: np.ndarray  # (n, 3) true rate in sensor axes, deg/s
    accel: np.ndarray  # (n, 3) true specific force in sensor axes, g
    k: np.ndarray  # (3,) scale factors of g = K m + b
    b: np.ndarray  # (3,) biases, deg/s of true rate
    fs: float  # nominal sample rate, Hz
    noise_dps: float  # white-noise std of the readings, deg/s


@dataclass(frozen=True, eq=False)
class SensorOutput:
    """The samples as the device delivers them. ``index`` maps each row to its generated sample."""

    t: np.ndarray  # (n,) device time stamps, s
    gyro: np.ndarray  # (n, 3) readings m, deg/s
    accel: np.ndarray  # (n, 3) accelerometer, g
    seq: np.ndarray  # (n,) int64 sample counter
    index: np.ndarray  # (n,) int64 row -> generated sample
    temp: np.ndarray | None = None  # (n,) degC
    full_scale_dps: float | None = None  # gyro range, set by a saturating effect
    t_true: np.ndarray | None = None  # (n,) true sample times, s

    def keep(self, mask: np.ndarray) -> SensorOutput:
        """The rows where ``mask`` is True (the others are lost); ``seq`` keeps the original counter."""
        mask = np.asarray(mask, dtype=bool)
        pick = lambda a: None if a is None else a[mask]  # noqa: E731
        return replace(
            self,
            t=self.t[mask],
            gyro=self.gyro[mask],
            accel=self.accel[mask],
            seq=self.seq[mask],
            index=self.index[mask],
            temp=pick(self.temp),
            t_true=pick(self.t_true),
        )


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, (tuple, list)):
        return [_jsonable(v) for v in value]
    return value


@dataclass(frozen=True)
class Effect:
    """Base class of simulator effects; override one or more of the three hooks."""

    name: ClassVar[str] = "effect"

    def on_trajectory(self, traj: Trajectory, rng: np.random.Generator) -> Trajectory:
        """Stage 1: change the true motion or the time base."""
        return traj

    def on_sensor(self, m: np.ndarray, ctx: SensorContext, rng: np.random.Generator) -> np.ndarray:
        """Stage 2: change the noise-free readings m (n, 3) in deg/s."""
        return m

    def on_output(self, out: SensorOutput, rng: np.random.Generator) -> SensorOutput:
        """Stage 3: change the delivered samples (clip, quantise, drop rows)."""
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready ``{"name": ..., <parameters>}``."""
        return {"name": self.name, **{f.name: _jsonable(getattr(self, f.name)) for f in fields(self)}}

    usage: ClassVar[str] = ""  # the CLI value format, for messages

    @classmethod
    def from_text(cls, value: str) -> Effect:
        """The effect from a CLI value: comma-separated numbers, passed to the constructor in order."""
        return cls(*_numbers(value, cls))


EFFECTS: dict[str, type[Effect]] = {}


def register_effect(cls: type[Effect]) -> type[Effect]:
    """Class decorator: make an effect available to ``parse_effect`` under its ``name``."""
    EFFECTS[cls.name] = cls
    return cls


def _numbers(value: str, cls: type[Effect]) -> list[float]:
    try:
        return [float(v) for v in value.split(",")] if value.strip() else []
    except ValueError:
        raise SimulationConfigError(f"effect {cls.name!r} needs {cls.usage or 'numbers'}; got {value!r}") from None


def parse_effect(name: str, value: str = "") -> Effect:
    """An effect from its name and CLI value, e.g. ``("bias_drift", "0.01,0,-0.02")`` or ``("saturation", "500")``."""
    cls = EFFECTS.get(name.strip().lower().replace("-", "_"))
    if cls is None:
        order = [n for n in CATALOGUE if n in EFFECTS] + sorted(set(EFFECTS) - set(CATALOGUE))
        known = "; ".join(f"{n}={EFFECTS[n].usage}" for n in order)
        raise SimulationConfigError(f"unknown effect {name!r}; known effects: {known}")
    try:
        return cls.from_text(value)
    except TypeError:
        raise SimulationConfigError(f"effect {cls.name!r} needs {cls.usage}; got {value!r}") from None


def effect_from_dict(d: dict[str, Any]) -> Effect:
    """The effect an ``Effect.to_dict()`` describes (e.g. from ``Truth.to_dict()["effects"]``)."""
    if not isinstance(d, dict) or "name" not in d:
        raise SimulationConfigError(f"an effect description is a dict with a 'name'; got {d!r}")
    cls = EFFECTS.get(str(d["name"]))
    if cls is None:
        raise SimulationConfigError(f"unknown effect {d['name']!r}; known effects: {', '.join(sorted(EFFECTS))}")
    params = {k: v for k, v in d.items() if k != "name"}
    try:
        return cls(**params)
    except TypeError as exc:
        raise SimulationConfigError(f"effect {cls.name!r}: {exc}") from None


def _vec3(value: Any, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape == ():
        arr = np.full(3, float(arr))
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise SimulationConfigError(f"{what} must be a finite number or 3 finite numbers (x, y, z); got {value!r}")
    return arr


def _usage_error(cls: type[Effect], value: str) -> SimulationConfigError:
    return SimulationConfigError(f"effect {cls.name!r} needs {cls.usage}; got {value!r}")


def _one_or_three(v: list[float], cls: type[Effect], value: str) -> float | list[float]:
    if len(v) not in (1, 3):
        raise _usage_error(cls, value)
    return v[0] if len(v) == 1 else v


def _positive(value: Any, what: str, allow_zero: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise SimulationConfigError(f"{what} must be a number; got {value!r}") from None
    if not np.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise SimulationConfigError(f"{what} must be a {'non-negative' if allow_zero else 'positive'} finite number; got {value!r}")
    return v


TEMP_RESOLUTION_C = 1.0 / 256.0  # temperature channel step (256 LSB/degC, a common IMU temperature sensor)


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
    rate_dps_per_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    temp_coeff_dps_per_c: np.ndarray | None = None
    temp_rise_c: float = 0.0
    temp_tau_s: float = 120.0
    temp0_c: float = 25.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "rate_dps_per_s", _vec3(self.rate_dps_per_s, "BiasDrift.rate_dps_per_s"))
        if self.temp_coeff_dps_per_c is not None:
            object.__setattr__(self, "temp_coeff_dps_per_c", _vec3(self.temp_coeff_dps_per_c, "BiasDrift.temp_coeff_dps_per_c"))
        rise = float(self.temp_rise_c)
        if not np.isfinite(rise):
            raise SimulationConfigError(f"BiasDrift.temp_rise_c must be a finite number of degC; got {self.temp_rise_c!r}")
        object.__setattr__(self, "temp_rise_c", rise)
        object.__setattr__(self, "temp_tau_s", _positive(self.temp_tau_s, "BiasDrift.temp_tau_s"))
        object.__setattr__(self, "temp0_c", float(self.temp0_c))

    @classmethod
    def from_text(cls, value: str) -> BiasDrift:
        groups = value.split(":")
        if len(groups) not in (1, 3, 4):
            raise _usage_error(cls, value)
        d = _one_or_three(_numbers(groups[0], cls), cls, value)
        if len(groups) == 1:
            return cls(d)
        c = _one_or_three(_numbers(groups[1], cls), cls, value)
        rest = [_numbers(g, cls) for g in groups[2:]]
        if any(len(r) != 1 for r in rest):
            raise _usage_error(cls, value)
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
        object.__setattr__(self, "tau_s", _positive(self.tau_s, "TemperatureRamp.tau_s"))
        object.__setattr__(self, "temp0_c", float(self.temp0_c))

    def on_output(self, out: SensorOutput, rng: np.random.Generator) -> SensorOutput:
        return _temperature_channel(out, self.temp0_c, self.rise_c, self.tau_s)


@register_effect
@dataclass(frozen=True, eq=False)
class AxisMisalignment(Effect):
    """Non-orthogonal sensor axes: an upper-triangular K (the closure estimator's extended model).

    Model: g = K m + b with K = [[k_x, K_xy, K_xz], [0, k_y, K_yz], [0, 0, k_z]];
    ``off_diagonal`` = (K_xy, K_xz, K_yz), absolute entries of K (dimensionless, like k). A general
    cross-axis matrix is a rotation times this form, and the rotation of the sensor frame is not
    observable from the gyro alone, so the lower entries are 0. Readings: m = K^-1 (g - b).
    CLI value: ``KXY,KXZ,KYZ``, e.g. ``axis_misalignment=0.01,0.005,-0.008``.
    """

    name: ClassVar[str] = "axis_misalignment"
    usage: ClassVar[str] = "KXY,KXZ,KYZ (upper off-diagonal entries of K)"
    off_diagonal: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        u = np.asarray(self.off_diagonal, dtype=float)
        if u.shape != (3,) or not np.all(np.isfinite(u)) or np.any(np.abs(u) >= 0.5):
            raise SimulationConfigError(
                f"AxisMisalignment.off_diagonal must be 3 numbers (K_xy, K_xz, K_yz) smaller than 0.5; got {self.off_diagonal!r}"
            )
        object.__setattr__(self, "off_diagonal", u)

    @classmethod
    def from_text(cls, value: str) -> AxisMisalignment:
        v = _numbers(value, cls)
        if len(v) != 3:
            raise _usage_error(cls, value)
        return cls(v)

    def matrix(self, k: np.ndarray) -> np.ndarray:
        """K (3, 3) for the scale factors k (3,)."""
        K = np.diag(np.asarray(k, dtype=float))
        K[[0, 0, 1], [1, 2, 2]] = self.off_diagonal
        return K

    def on_sensor(self, m: np.ndarray, ctx: SensorContext, rng: np.random.Generator) -> np.ndarray:
        # m enters as diag(k)^-1 (g - b); the readings of the non-orthogonal sensor are K^-1 (g - b).
        return np.linalg.solve(self.matrix(ctx.k), (m * ctx.k).T).T


@register_effect
@dataclass(frozen=True, eq=False)
class GSensitivity(Effect):
    """Linear-acceleration sensitivity of the gyro (needs the accelerometer to be modelled).

    Model: g = K (m - G a) + b, i.e. readings m = K^-1 (g - b) + G a, with a the specific force in g
    (sensor axes; (0, 0, 1) lying flat) and G = ``matrix_dps_per_g`` (3, 3) in (deg/s of reading)/g,
    row = gyro axis, column = acceleration axis. At rest the term adds G a to the still readings,
    which the rest alone cannot tell from b; turns move a through other directions.
    CLI value: ``G`` (G = G I), ``GX,GY,GZ`` (diagonal) or 9 numbers row by row.
    """

    name: ClassVar[str] = "g_sensitivity"
    usage: ClassVar[str] = "G, GX,GY,GZ (diagonal) or 9 numbers row-major ((deg/s)/g)"
    matrix_dps_per_g: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))

    def __post_init__(self) -> None:
        G = np.asarray(self.matrix_dps_per_g, dtype=float)
        if G.shape == ():
            G = np.eye(3) * G
        elif G.shape == (3,):
            G = np.diag(G)
        elif G.shape == (9,):
            G = G.reshape(3, 3)
        if G.shape != (3, 3) or not np.all(np.isfinite(G)):
            raise SimulationConfigError(
                f"GSensitivity.matrix_dps_per_g must be a number, 3 numbers (diagonal) or a 3x3 matrix; got {self.matrix_dps_per_g!r}"
            )
        object.__setattr__(self, "matrix_dps_per_g", G)

    @classmethod
    def from_text(cls, value: str) -> GSensitivity:
        v = _numbers(value, cls)
        if len(v) not in (1, 3, 9):
            raise _usage_error(cls, value)
        return cls(v[0] if len(v) == 1 else v)

    def on_sensor(self, m: np.ndarray, ctx: SensorContext, rng: np.random.Generator) -> np.ndarray:
        return m + ctx.accel @ self.matrix_dps_per_g.T


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
    asymmetry: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        s = _vec3(self.asymmetry, "ScaleAsymmetry.asymmetry")
        if np.any(np.abs(s) >= 0.5):
            raise SimulationConfigError(f"ScaleAsymmetry.asymmetry must be smaller than 0.5 in size; got {self.asymmetry!r}")
        object.__setattr__(self, "asymmetry", s)

    @classmethod
    def from_text(cls, value: str) -> ScaleAsymmetry:
        return cls(_one_or_three(_numbers(value, cls), cls, value))

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
    coeff: np.ndarray = field(default_factory=lambda: np.zeros(3))
    ref_rate_dps: float = 1000.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "coeff", _vec3(self.coeff, "ScaleNonlinearity.coeff"))
        object.__setattr__(self, "ref_rate_dps", _positive(self.ref_rate_dps, "ScaleNonlinearity.ref_rate_dps"))

    @classmethod
    def from_text(cls, value: str) -> ScaleNonlinearity:
        groups = value.split(":")
        if len(groups) not in (1, 2):
            raise _usage_error(cls, value)
        n = _one_or_three(_numbers(groups[0], cls), cls, value)
        if len(groups) == 1:
            return cls(n)
        r0 = _numbers(groups[1], cls)
        if len(r0) != 1:
            raise _usage_error(cls, value)
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
class SampleLoss(Effect):
    """Lost samples (radio link or buffer overrun): rows missing from the recording.

    Each generated sample starts a lost burst of ``burst`` samples with probability ``prob``, and the
    samples in ``ranges`` ([start, end) generated-sample indices) are lost too; the expected lost
    fraction is 1 - (1 - prob)^burst. The kept rows keep their time stamps and sample counter, so a
    gap shows as a step > 1 in ``seq`` and a step > 1 / fs in ``t``; the readings of the kept rows
    are unchanged (the rotation during a gap is simply not measured). CLI value: ``PROB[,BURST]``.
    """

    name: ClassVar[str] = "sample_loss"
    usage: ClassVar[str] = "PROB[,BURST] (probability per sample, samples per loss)"
    prob: float = 0.0
    ranges: tuple[tuple[int, int], ...] = ()
    burst: int = 1

    def __post_init__(self) -> None:
        if not (0.0 <= float(self.prob) < 1.0):
            raise SimulationConfigError(f"SampleLoss.prob must be in [0, 1); got {self.prob!r}")
        if int(self.burst) < 1:
            raise SimulationConfigError(f"SampleLoss.burst must be a whole number >= 1; got {self.burst!r}")
        try:
            ranges = tuple((int(a), int(b)) for a, b in self.ranges)
        except (TypeError, ValueError):
            raise SimulationConfigError(
                f"SampleLoss.ranges must be pairs (start, end) of sample indices; got {self.ranges!r}"
            ) from None
        for a, b in ranges:
            if a < 0 or b <= a:
                raise SimulationConfigError(f"SampleLoss range ({a}, {b}) must have 0 <= start < end")
        object.__setattr__(self, "prob", float(self.prob))
        object.__setattr__(self, "burst", int(self.burst))
        object.__setattr__(self, "ranges", ranges)

    @classmethod
    def from_text(cls, value: str) -> SampleLoss:
        v = _numbers(value, cls)
        if len(v) not in (1, 2) or (len(v) == 2 and v[1] != int(v[1])):
            raise SimulationConfigError(f"effect 'sample_loss' needs {cls.usage}; got {value!r}")
        return cls(prob=v[0], burst=int(v[1]) if len(v) == 2 else 1)

    def lost_mask(self, index: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """True for each generated sample index in ``index`` that is lost."""
        n = int(index.max()) + 1 if index.size else 0
        lost = np.zeros(n + self.burst, dtype=bool)
        if self.prob > 0.0:
            starts = np.flatnonzero(rng.random(n) < self.prob)
            for offset in range(self.burst):
                lost[starts + offset] = True
        for a, b in self.ranges:
            lost[a : min(b, n)] = True
        return lost[index]

    def on_output(self, out: SensorOutput, rng: np.random.Generator) -> SensorOutput:
        return out.keep(~self.lost_mask(out.index, rng))


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
    full_scale_dps: float = 2000.0
    resolution_dps: float | None = None

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


_UP = np.array([0.0, 0.0, 1.0])  # specific force at rest in the start frame, g


def _smoothstep(u: np.ndarray) -> np.ndarray:
    return u * u * (3.0 - 2.0 * u)


@register_effect
@dataclass(frozen=True, eq=False)
class PlacementError(Effect):
    """The device is not put back exactly in its starting pose after each turn.

    Turn j ends rotated by the world-frame (start-frame, z up) rotation Exp(e_j) from where a
    closing turn would leave it, e_j = (tilt about x, tilt about y, heading about z) in deg. The
    extra rotation is done smoothly over the last ``ramp_fraction`` of the turn, acts on the true
    motion (so the accelerometer sees the tilt) and stays for the rest of the recording: poses
    after the turn are Exp(e_j) ... Exp(e_1) R(t). Consequences, for a turn starting at true pose
    R_s (body to start frame):

    - the turn no longer closes: the product of Exp(g dt) over it is Exp(R_s^T e_j) (body axes);
    - the accelerometer at rest after the turn reads (Exp(e_j) R_s)^T (0, 0, 1): the tilt
      components of e_j are measurable, the heading component (about the vertical) is not.

    Parameters: ``std_deg`` std of each tilt component, ``heading_std_deg`` std of the heading
    component (None: same as ``std_deg``); ``errors_deg`` (J, 3) fixes e_j for the J turns instead
    of drawing them N(0, diag(std^2, std^2, heading_std^2)). CLI value: ``STD[,HEADING_STD]`` (deg).
    """

    name: ClassVar[str] = "placement_error"
    usage: ClassVar[str] = "STD[,HEADING_STD] (deg per turn)"
    std_deg: float = 0.0
    heading_std_deg: float | None = None
    errors_deg: np.ndarray | None = None
    ramp_fraction: float = 0.25

    def __post_init__(self) -> None:
        object.__setattr__(self, "std_deg", _positive(self.std_deg, "PlacementError.std_deg", allow_zero=True))
        if self.heading_std_deg is not None:
            object.__setattr__(
                self, "heading_std_deg", _positive(self.heading_std_deg, "PlacementError.heading_std_deg", allow_zero=True)
            )
        if self.errors_deg is not None:
            e = np.asarray(self.errors_deg, dtype=float)
            if e.ndim != 2 or e.shape[1] != 3 or not np.all(np.isfinite(e)) or np.any(np.abs(e) > 45):
                raise SimulationConfigError(
                    "PlacementError.errors_deg must be one row (tilt x, tilt y, heading) in deg per turn, each under 45; "
                    f"got {self.errors_deg!r}"
                )
            object.__setattr__(self, "errors_deg", e)
        f = float(self.ramp_fraction)
        if not (0.0 < f <= 1.0):
            raise SimulationConfigError(f"PlacementError.ramp_fraction must be in (0, 1]; got {self.ramp_fraction!r}")
        object.__setattr__(self, "ramp_fraction", f)

    @classmethod
    def from_text(cls, value: str) -> PlacementError:
        v = _numbers(value, cls)
        if len(v) not in (1, 2):
            raise _usage_error(cls, value)
        return cls(*v)

    @property
    def stds_deg(self) -> np.ndarray:
        """Standard deviations of (tilt x, tilt y, heading), deg."""
        h = self.std_deg if self.heading_std_deg is None else self.heading_std_deg
        return np.array([self.std_deg, self.std_deg, h])

    def draw_errors(self, n_turns: int, rng: np.random.Generator) -> np.ndarray:
        """e_j (n_turns, 3) in deg, drawn N(0, diag(stds^2))."""
        return rng.standard_normal((n_turns, 3)) * self.stds_deg

    def on_trajectory(self, traj: Trajectory, rng: np.random.Generator) -> Trajectory:
        turns = [s for s in traj.stages if s.kind == "turn"]
        if not turns:
            return traj
        errs = self.errors_deg if self.errors_deg is not None else self.draw_errors(len(turns), rng)
        if errs.shape[0] != len(turns):
            raise SimulationConfigError(f"PlacementError.errors_deg has {errs.shape[0]} rows but the protocol has {len(turns)} turns")
        n = traj.n
        left = np.tile(Rotation.identity().as_quat(), (n + 1, 1))
        cum = Rotation.identity()
        ramps: list[tuple[int, int]] = []
        for st, e in zip(turns, np.radians(errs), strict=False):
            L = max(1, int(round(self.ramp_fraction * (st.end - st.start))))
            a = st.end - L
            s = _smoothstep(np.arange(L + 1) / L)
            left[a : st.end + 1] = (Rotation.from_rotvec(s[:, None] * e) * cum).as_quat()
            cum = Rotation.from_rotvec(e) * cum
            left[st.end + 1 :] = cum.as_quat()
            ramps.append((a, st.end))
        attitude = Rotation.from_quat(left) * traj.attitude
        rate = traj.rate.copy()
        dt = np.diff(traj.t, append=traj.t[-1] + (traj.t[-1] - traj.t[-2] if n > 1 else traj.dt))
        idx = np.concatenate([np.arange(a, b) for a, b in ramps])
        rel = attitude[idx].inv() * attitude[idx + 1]
        rate[idx] = np.degrees(rel.as_rotvec()) / dt[idx, None]
        accel = attitude[:n].inv().apply(_UP)
        return replace(traj, rate=rate, attitude=attitude, accel=accel)


@register_effect
@dataclass(frozen=True, eq=False)
class ClockError(Effect):
    """The device's sample clock runs at (1 + e) times true time.

    Model: t_device = (1 + e) t_true. The device stamps its samples i / fs (its nominal rate, also
    in the metadata) but really samples at fs (1 + e); the gyro measures true rates, so integrating
    the readings over the recording's (device) times gives (1 + e) times the true angle: over
    device time the data follow g = (K m + b) / (1 + e), i.e. a fit of eq. (1) returns k / (1 + e)
    and b / (1 + e). Only a clock outside the device (host receive times) tells e apart from k.
    ``error`` = e, a fraction (1e-4 = 100 ppm; consumer IMU oscillators +-1-3 %). CLI value: ``E``.
    """

    name: ClassVar[str] = "clock_error"
    usage: ClassVar[str] = "E (fraction: 0.01 = device clock 1 % fast)"
    error: float = 0.0

    def __post_init__(self) -> None:
        try:
            e = float(self.error)
        except (TypeError, ValueError):
            raise SimulationConfigError(f"ClockError.error must be a number; got {self.error!r}") from None
        if not (np.isfinite(e) and abs(e) < 0.5):
            raise SimulationConfigError(f"ClockError.error must be a fraction between -0.5 and 0.5; got {self.error!r}")
        object.__setattr__(self, "error", e)

    def on_trajectory(self, traj: Trajectory, rng: np.random.Generator) -> Trajectory:
        s = 1.0 + self.error
        # Same poses and same device stamps; the true clock is 1 + e slower, so the true rates are higher.
        return replace(traj, t=traj.t / s, rate=traj.rate * s)


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
    sigma_dps: float = 0.0
    tau_s: float = 30.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "sigma_dps", _positive(self.sigma_dps, "BiasInstability.sigma_dps", allow_zero=True))
        object.__setattr__(self, "tau_s", _positive(self.tau_s, "BiasInstability.tau_s"))

    @classmethod
    def from_text(cls, value: str) -> BiasInstability:
        v = _numbers(value, cls)
        if len(v) not in (1, 2):
            raise _usage_error(cls, value)
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


# The effects of the simulation-vs-reality catalogue, in the order the documentation lists them.
CATALOGUE: tuple[str, ...] = (
    "bias_drift",
    "axis_misalignment",
    "g_sensitivity",
    "scale_asymmetry",
    "scale_nonlinearity",
    "saturation",
    "sample_loss",
    "placement_error",
    "clock_error",
    "bias_instability",
)


def check_effects(effects: Sequence[Effect]) -> tuple[Effect, ...]:
    """The effects as a tuple, after checking each is an ``Effect`` instance."""
    out = tuple(effects)
    for e in out:
        if not isinstance(e, Effect):
            raise SimulationConfigError(f"effects must be calib.effects.Effect instances (e.g. BiasDrift(...)); got {type(e).__name__}")
    return out
