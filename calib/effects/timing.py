"""Errors of the sample stream: samples lost on the link, and a device clock that runs off true time."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from calib.effects.base import Effect, SensorOutput, SimulationConfigError, Trajectory, numbers_of, register_effect
from calib.effects.spec import DrawContext, EffectSpec, MagnitudeRange, log_uniform

LOSS_BURST = (1, 12)  # samples lost together: one BLE packet carries 1-12 samples


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
    spec: ClassVar[EffectSpec] = EffectSpec(
        rank=6,
        equation="rows missing; `seq` and `t` of the kept rows show the gap",
        parameters="probability per sample, burst length",
        drawn=MagnitudeRange(
            0.002, 0.03, "", "expected fraction of samples lost",
            "Bluetooth Low Energy links of wearables lose 0.1-3 % of packets of 1-12 samples",
            drawn_as=f"0.2-3 % of the samples, in bursts of {LOSS_BURST[0]}-{LOSS_BURST[1]}",
        ),
        reveal="record the device's sample counter (or its own timestamps)",
        diagnosis_model="rows at their counter (or timestamp) sample numbers; the lost readings put back by cubic interpolation",
        diagnosis_parameters="lost samples",
    )
    prob: float = 0.0
    ranges: tuple[tuple[int, int], ...] = ()
    burst: int = 1

    @classmethod
    def draw(cls, rng: np.random.Generator, ctx: DrawContext) -> tuple[SampleLoss, float]:
        frac = log_uniform(rng, cls.spec.drawn.low, cls.spec.drawn.high)
        burst = int(rng.integers(LOSS_BURST[0], LOSS_BURST[1] + 1))
        return cls(prob=1.0 - (1.0 - frac) ** (1.0 / burst), burst=burst), frac
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
        v = numbers_of(value, cls)
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
    spec: ClassVar[EffectSpec] = EffectSpec(
        rank=8,
        equation="t_device = (1 + e) t_true: over device time g = (K m + b) / (1 + e)",
        parameters="e (fraction)",
        drawn=MagnitudeRange(
            0.003, 0.03, "", "|e|, fraction the device clock runs fast (+) or slow (-)",
            "internal oscillators of consumer IMUs set the output data rate to +-1-3 %",
            drawn_as="|e| 0.3-3 %, either sign",
        ),
        reveal="record the host's receive time of each sample (the host_t column) beside the device's sample counter",
        diagnosis_model="host time = c + n P / (1 + e)",
        diagnosis_parameters="e",
    )
    error: float = 0.0

    @classmethod
    def draw(cls, rng: np.random.Generator, ctx: DrawContext) -> tuple[ClockError, float]:
        mag = log_uniform(rng, cls.spec.drawn.low, cls.spec.drawn.high)
        return cls(mag * rng.choice([-1.0, 1.0])), mag
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
