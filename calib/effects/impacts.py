"""Knocks: the device put down (and picked up) by hand rings briefly, a short broadband burst in its readings."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from calib.effects.base import Effect, SensorContext, SimulationConfigError, numbers_of, positive, register_effect, usage_error

MOVING_DPS = 2.0  # the true rate above which the device is in a motion (its start and end are the knocks)
LIFT_SHARE = 0.3  # picking the device up knocks it this hard, relative to putting it down


@register_effect
@dataclass(frozen=True)
class Impacts(Effect):
    """A knock where each motion ends (the device put down on the table) and a weaker one where it starts.

    Model: at each end of a motion of the true rate (``MOVING_DPS``), the device rings about a random axis through
    the angle (peak / 2 pi f) e^(-t/tau) sin(2 pi f t), over 6 tau, and the readings get that angle's rate (sample
    to sample), ``peak_dps`` at its largest at a put-down and ``LIFT_SHARE`` of it at a pick-up, with f = ``freq_hz``
    and tau = ``decay_s``. The angle starts and ends at 0: a knock shakes the device, it does not turn it. Landing
    in a rest's first or last samples, such a burst widens the rest's scatter far beyond its white noise unless the
    noise measures resist it. CLI value: ``PEAK[,FREQ[,DECAY]]`` (deg/s, Hz, s).
    """

    name: ClassVar[str] = "impacts"
    usage: ClassVar[str] = "PEAK[,FREQ_HZ[,DECAY_S]] (deg/s, Hz, s)"
    peak_dps: float = 20.0
    freq_hz: float = 30.0
    decay_s: float = 0.02

    def __post_init__(self) -> None:
        object.__setattr__(self, "peak_dps", positive(self.peak_dps, "Impacts.peak_dps", allow_zero=True))
        object.__setattr__(self, "freq_hz", positive(self.freq_hz, "Impacts.freq_hz"))
        object.__setattr__(self, "decay_s", positive(self.decay_s, "Impacts.decay_s"))
        if self.decay_s > 1.0:
            raise SimulationConfigError(f"Impacts.decay_s is a knock's ring-down time, under 1 s; got {self.decay_s!r}")

    @classmethod
    def typical(cls) -> Impacts:
        """A device put down on a table by hand: a 20 deg/s ring at 30 Hz, gone in about 0.1 s."""
        return cls()

    @classmethod
    def from_text(cls, value: str) -> Impacts:
        v = numbers_of(value, cls)
        if not 1 <= len(v) <= 3:
            raise usage_error(cls, value)
        return cls(*v)

    def on_sensor(self, m: np.ndarray, ctx: SensorContext, rng: np.random.Generator) -> np.ndarray:
        moving = np.linalg.norm(ctx.rate, axis=1) > MOVING_DPS
        edges = np.flatnonzero(np.diff(moving.astype(np.int8)))
        if edges.size == 0 or self.peak_dps == 0:
            return m
        out = m.copy()
        t = ctx.t
        for e in edges:
            put_down = bool(moving[e]) and not moving[e + 1]
            i0 = e + 1 if put_down else e
            peak = self.peak_dps * (1.0 if put_down else LIFT_SHARE)
            span = np.flatnonzero((t >= t[i0]) & (t < t[i0] + 6 * self.decay_s))
            if span.size < 3:
                continue
            # the ring is the change of a small angle that starts and ends at 0, so the knock turns the device by
            # nothing: the readings are its sample-to-sample differences
            w = 2 * np.pi * self.freq_hz
            tt = t[span] - t[i0]
            angle = (peak / w) * np.exp(-tt / self.decay_s) * np.sin(w * tt)
            angle[-1] = 0.0
            ring = np.diff(angle) / np.diff(tt)
            axis = rng.standard_normal(3)
            axis /= np.linalg.norm(axis)
            out[span[:-1]] += ring[:, None] * axis
        return out
