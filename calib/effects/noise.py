"""Noise that changes with the motion: a gyroscope noisier while it turns than while it rests."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from calib.effects.base import Effect, SensorContext, SimulationConfigError, numbers_of, one_or_three, positive, register_effect, vec3


@register_effect
@dataclass(frozen=True)
class MotionNoise(Effect):
    """White noise that grows while the device turns.

    Model: while the true rate's magnitude exceeds ``threshold_dps`` (deg/s), the readings carry extra white
    noise of variance (``ratio`` - 1) sigma^2 per axis on top of the white noise sigma of every sample, so their
    noise variance is ``ratio`` times the rests' (``ratio`` >= 1, one number or one per axis). The rotation
    integrated over a motion then scatters ``ratio`` times more (in variance) than the rests' noise predicts;
    ``calib.noise.motion`` measures it in the top of the band. CLI value: ``RATIO`` or ``RX,RY,RZ``, optionally followed by ``,THRESHOLD``.
    """

    name: ClassVar[str] = "motion_noise"
    usage: ClassVar[str] = "RATIO or RX,RY,RZ, then optionally THRESHOLD (noise variance turning over at rest; deg/s)"
    ratio: np.ndarray = field(default_factory=lambda: np.ones(3))
    threshold_dps: float = 5.0

    def __post_init__(self) -> None:
        r = vec3(self.ratio, "MotionNoise.ratio")
        if np.any(r < 1.0):
            raise SimulationConfigError(f"MotionNoise.ratio is a variance ratio of at least 1; got {self.ratio!r}")
        object.__setattr__(self, "ratio", r)
        object.__setattr__(self, "threshold_dps", positive(self.threshold_dps, "MotionNoise.threshold_dps", allow_zero=True))

    @classmethod
    def from_text(cls, value: str) -> MotionNoise:
        v = numbers_of(value, cls)
        if len(v) in (2, 4):
            return cls(one_or_three(v[:-1], cls, value), v[-1])
        return cls(one_or_three(v, cls, value))

    def on_sensor(self, m: np.ndarray, ctx: SensorContext, rng: np.random.Generator) -> np.ndarray:
        moving = np.linalg.norm(ctx.rate, axis=1) > self.threshold_dps
        extra = ctx.noise_dps * np.sqrt(self.ratio - 1.0) * rng.standard_normal(m.shape)
        return m + extra * moving[:, None]
