"""Physical effects the protocol simulator can switch on, and the pipeline stages they act on.

The simulator (``calib.simulator``) produces a recording in three stages; an ``Effect`` may act on
any of them by overriding the matching hook (the default hooks change nothing):

1. ``on_trajectory(traj, rng) -> Trajectory`` — the true motion and time base, before the sensor:
   placement error of the sensor on the body (rotate ``rate`` and ``accel`` into the sensor axes),
   clock error (true sample times ``t`` differ from the stamps ``t_device`` the device reports).
2. ``on_sensor(m, ctx, rng) -> m`` — the sensor model from true rate to reading. ``m`` enters as the
   ideal reading (g - b) / k of eq. (1), before white noise; ``ctx`` gives the true rate, the specific
   force, the true times and the parameters. Misalignment, g-sensitivity, scale asymmetry and
   nonlinearity, bias drift and bias instability belong here.
3. ``on_output(out, rng) -> SensorOutput`` — what leaves the device, after white noise: saturation,
   quantisation, lost samples (drop rows with ``SensorOutput.keep``; ``seq`` then shows the gaps).

Within a stage, effects run in the order given. Each effect draws from its own random generator,
so switching one effect on does not change the motion, the noise or another effect's draws.
``to_dict()`` (all dataclass fields plus ``name``) is what ``Truth.to_dict()["effects"]`` lists.

Adding an effect: subclass ``Effect`` as a frozen dataclass with a ``name``, override the hooks it
needs, decorate it with ``@register_effect`` so that ``parse_effect`` (the CLI's ``--effect
NAME=VALUE``) knows it, and give it ``from_text`` if its CLI value is not just its numeric fields.

Units: rates deg/s, times s, specific force g, angles deg.
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
    Log(attitude[i]^-1 attitude[i+1]) / dt; ``attitude`` holds the n + 1 body-to-start-frame poses at
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

    def keep(self, mask: np.ndarray) -> "SensorOutput":
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
    def from_text(cls, value: str) -> "Effect":
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
        known = ", ".join(f"{n}={c.usage}" for n, c in sorted(EFFECTS.items()))
        raise SimulationConfigError(f"unknown effect {name!r}; known effects: {known}")
    try:
        return cls.from_text(value)
    except TypeError:
        raise SimulationConfigError(f"effect {cls.name!r} needs {cls.usage}; got {value!r}") from None


def _vec3(value: Any, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape == ():
        arr = np.full(3, float(arr))
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise SimulationConfigError(f"{what} must be a finite number or 3 finite numbers (x, y, z); got {value!r}")
    return arr


@register_effect
@dataclass(frozen=True)
class BiasDrift(Effect):
    """Linear bias drift: b(t) = b + rate_dps_per_s * t (deg/s of true rate, t in s from the first sample)."""

    name: ClassVar[str] = "bias_drift"
    usage: ClassVar[str] = "RATE or RX,RY,RZ (deg/s per s)"
    rate_dps_per_s: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @classmethod
    def from_text(cls, value: str) -> "BiasDrift":
        v = _numbers(value, cls)
        if len(v) not in (1, 3):
            raise SimulationConfigError(f"effect 'bias_drift' needs {cls.usage}; got {value!r}")
        return cls(v[0] if len(v) == 1 else v)

    def __post_init__(self) -> None:
        object.__setattr__(self, "rate_dps_per_s", _vec3(self.rate_dps_per_s, "BiasDrift.rate_dps_per_s"))

    def on_sensor(self, m: np.ndarray, ctx: SensorContext, rng: np.random.Generator) -> np.ndarray:
        # m = (g - b(t)) / k: the extra bias enters in true-rate units, like b.
        return m - np.outer(ctx.t - ctx.t[0], self.rate_dps_per_s) / ctx.k


@register_effect
@dataclass(frozen=True)
class SampleLoss(Effect):
    """Lost samples: each sample starts a lost burst of ``burst`` samples with probability ``prob``,
    and the samples in ``ranges`` ([start, end) generated-sample indices) are lost too."""

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
    def from_text(cls, value: str) -> "SampleLoss":
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
    """Gyro range: readings are quantised to ``resolution_dps`` (if given) and clipped at +-``full_scale_dps``."""

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


def check_effects(effects: Sequence[Effect]) -> tuple[Effect, ...]:
    """The effects as a tuple, after checking each is an ``Effect`` instance."""
    out = tuple(effects)
    for e in out:
        if not isinstance(e, Effect):
            raise SimulationConfigError(
                f"effects must be calib.effects.Effect instances (e.g. BiasDrift(...)); got {type(e).__name__}"
            )
    return out
