"""What every effect shares: the trajectory and sensor context it acts on, the Effect base class, its registry
(EFFECTS, ``catalogue()``), and how an effect is parsed from the command line or rebuilt from its dict."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from typing import Any, ClassVar

import numpy as np
from scipy.spatial.transform import Rotation

from calib.effects.spec import DrawContext, EffectSpec
from calib.errors import GyrocalError
from calib.stages.stage import Stage


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
    spec: ClassVar[EffectSpec | None] = None  # set by the effects of the simulation-vs-reality catalogue

    @classmethod
    def draw(cls, rng: np.random.Generator, ctx: DrawContext) -> tuple[Effect, float]:
        """A concealed instance of this effect and its magnitude (unit of ``spec.drawn``), drawn in ``spec.drawn``."""
        raise SimulationConfigError(f"effect {cls.name!r} is not in the catalogue: it has no concealed draw")

    @classmethod
    def from_text(cls, value: str) -> Effect:
        """The effect from a CLI value: comma-separated numbers, passed to the constructor in order."""
        return cls(*numbers_of(value, cls))


EFFECTS: dict[str, type[Effect]] = {}


def register_effect(cls: type[Effect]) -> type[Effect]:
    """Class decorator: make an effect available to ``parse_effect`` under its ``name``."""
    EFFECTS[cls.name] = cls
    return cls


def numbers_of(value: str, cls: type[Effect]) -> list[float]:
    try:
        return [float(v) for v in value.split(",")] if value.strip() else []
    except ValueError:
        raise SimulationConfigError(f"effect {cls.name!r} needs {cls.usage or 'numbers'}; got {value!r}") from None


def parse_effect(name: str, value: str = "") -> Effect:
    """An effect from its name and CLI value, e.g. ``("bias_drift", "0.01,0,-0.02")`` or ``("saturation", "500")``."""
    cls = EFFECTS.get(name.strip().lower().replace("-", "_"))
    if cls is None:
        known = "; ".join(f"{n}={EFFECTS[n].usage}" for n in registered())
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


def vec3(value: Any, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape == ():
        arr = np.full(3, float(arr))
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise SimulationConfigError(f"{what} must be a finite number or 3 finite numbers (x, y, z); got {value!r}")
    return arr


def usage_error(cls: type[Effect], value: str) -> SimulationConfigError:
    return SimulationConfigError(f"effect {cls.name!r} needs {cls.usage}; got {value!r}")


def one_or_three(v: list[float], cls: type[Effect], value: str) -> np.ndarray:
    """One number (for every axis) or three (x, y, z), as an array the effect takes."""
    if len(v) not in (1, 3):
        raise usage_error(cls, value)
    return np.asarray(v[0] if len(v) == 1 else v, dtype=float)


def positive(value: Any, what: str, allow_zero: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise SimulationConfigError(f"{what} must be a number; got {value!r}") from None
    if not np.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise SimulationConfigError(f"{what} must be a {'non-negative' if allow_zero else 'positive'} finite number; got {value!r}")
    return v


def catalogue() -> tuple[str, ...]:
    """The effects of the simulation-vs-reality catalogue (those with a ``spec``), in the documentation's order."""
    specced = [cls for cls in EFFECTS.values() if cls.spec is not None]
    return tuple(cls.name for cls in sorted(specced, key=lambda c: c.spec.rank if c.spec else 0))


def registered() -> list[str]:
    """Every registered effect's name: the catalogue in its order, then the others (e.g. ``temperature``) by name."""
    cat = catalogue()
    return [*cat, *sorted(set(EFFECTS) - set(cat))]


def catalogue_specs() -> dict[str, EffectSpec]:
    """Each catalogue effect's spec, by name, in the catalogue's order."""
    return {name: spec for name in catalogue() if (spec := EFFECTS[name].spec) is not None}


def check_effects(effects: Sequence[Effect]) -> tuple[Effect, ...]:
    """The effects as a tuple, after checking each is an ``Effect`` instance."""
    out = tuple(effects)
    for e in out:
        if not isinstance(e, Effect):
            raise SimulationConfigError(f"effects must be calib.effects.Effect instances (e.g. BiasDrift(...)); got {type(e).__name__}")
    return out
