"""The simulated wearables the service can run in its own process (`gyrocal serve --mock N`), offered to it
through the ``gyrocal.simulators`` entry point: the service knows only this module's names, never the
classes behind them."""

from __future__ import annotations

from wearable_protocol.models import model as device_model

from .scenarios import SCENARIOS
from .sources import ScriptedSource
from .vendors import WEARABLES
from .wearable import Wearable

scenarios: tuple[str, ...] = tuple(SCENARIOS)
models: tuple[str, ...] = tuple(WEARABLES)


def rates(model: str) -> tuple[float, ...]:
    """The rates a simulated wearable of ``model`` offers (Hz)."""
    return device_model(model).rates_hz


def wearable(*, seed: int, scenario: str, speed: float, name: str, rate_hz: float | None, noise_dps: float,
             model: str = "gyrocal") -> Wearable:
    """A simulated wearable speaking ``model``'s protocol whose clinician performs ``scenario`` whenever
    streaming starts."""
    source = ScriptedSource(seed=seed, scenario=scenario, noise_dps=noise_dps)
    return WEARABLES[model](source, seed=seed, speed=speed, name=name, rate_hz=rate_hz)
