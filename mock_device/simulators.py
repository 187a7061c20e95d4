"""The simulated wearables the service can run in its own process (`gyrocal serve --mock N`), offered to it
through the ``gyrocal.simulators`` entry point: the service knows only this module's three names, never the
classes behind them."""

from __future__ import annotations

import wearable_protocol as wp

from .scenarios import SCENARIOS
from .sources import ScriptedSource
from .wearable import Wearable

scenarios: tuple[str, ...] = tuple(SCENARIOS)
rates_hz: tuple[float, ...] = wp.SUPPORTED_RATES_HZ


def wearable(*, seed: int, scenario: str, speed: float, name: str, rate_hz: float, noise_dps: float) -> Wearable:
    """A simulated wearable whose clinician performs ``scenario`` whenever streaming starts."""
    source = ScriptedSource(seed=seed, scenario=scenario, noise_dps=noise_dps)
    return Wearable(source, seed=seed, speed=speed, name=name, rate_hz=rate_hz)
