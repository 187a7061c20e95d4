"""What gyrocal knows about one physical effect, in one place: ``EffectSpec``.

Each effect class of the catalogue carries its spec (``Effect.spec``) next to its simulation hooks.
The spec is what the rest of the tool reads instead of keeping its own table:

- the concealed-effect generator draws magnitudes in ``drawn`` (``Effect.draw``);
- the diagnosis sizes its tests with ``typical``, tells the user what would ``reveal`` an effect it
  cannot see and what would ``distinguish`` rivals, and names model parameters with ``model_params``;
- the CLI's ``--effect`` help, ``gyrocal effects`` and the documentation's tables are written from
  ``equation``, ``parameters``, ``diagnosis_model`` and the class's ``usage``.

Units are those of the effect's own parameters (rates deg/s, times s, specific force g, angles deg).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class MagnitudeRange:
    """The drawn range of an effect's magnitude: [low, high] in ``unit``; ``what`` the magnitude is, ``why`` this range."""

    low: float
    high: float
    unit: str
    what: str
    why: str
    drawn_as: str = ""  # how the draw departs from log-uniform in [low, high], when it does

    def text(self) -> str:
        """The range as the documentation states it, e.g. ``0.02-0.2 deg/s``."""
        return self.drawn_as or f"{self.low:g}-{self.high:g}{' ' + self.unit if self.unit else ''}"


@dataclass(frozen=True)
class DrawContext:
    """What a concealed draw may depend on: the protocol's turns, its length, the peak reading, the warm-up."""

    turns: int
    duration_s: float
    peak_dps: float
    temperature: tuple[float, float, float] | None  # (T0 degC, rise degC, tau s) when the recording has a temperature channel


@dataclass(frozen=True)
class EffectSpec:
    """One effect's model, sizes and advice; see the module docstring for who reads which field."""

    rank: int  # position in the catalogue; the concealed generator keys its random streams by it
    equation: str  # the simulator's model, in the notation of docs/effects.md
    parameters: str  # the model's parameters and their units
    drawn: MagnitudeRange
    reveal: str  # the motion or channel that makes the effect visible
    diagnosis_model: str  # how the diagnosis models it
    diagnosis_parameters: str
    typical: float | None = None  # a typical magnitude (unit of ``drawn``) the diagnosis sizes its test with
    typical_text: str = ""
    typical_extra: Mapping[str, float] = field(default_factory=dict)  # other typical parameters (e.g. tau_s)
    distinguish: str = ""  # what tells it apart from rivals explaining the same misfit
    model_params: Mapping[str, tuple[str, ...]] = field(default_factory=dict)  # diagnosis model term -> parameter names


def log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    """One draw, log-uniform in [low, high]."""
    return float(np.exp(rng.uniform(np.log(low), np.log(high))))


def spread(rng: np.random.Generator, largest: float, shape: tuple[int, ...] = (3,)) -> np.ndarray:
    """Random signs and shares, the largest component exactly ``largest`` in size."""
    u = rng.uniform(-1.0, 1.0, shape)
    return largest * u / np.max(np.abs(u))
