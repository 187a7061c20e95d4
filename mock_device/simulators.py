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


def rates_instead(model: str, rate_hz: float) -> str | None:
    """None when a simulated wearable of ``model`` offers ``rate_hz``; else the rates it does offer, in words."""
    m = device_model(model)
    return None if m.offers_rate(rate_hz) else m.rates_text()


def wearable(*, seed: int, scenario: str, speed: float, name: str, rate_hz: float | None, noise_dps: float,
             model: str = "gyrocal") -> Wearable:
    """A simulated wearable speaking ``model``'s protocol whose clinician performs ``scenario`` whenever
    streaming starts."""
    source = ScriptedSource(seed=seed, scenario=scenario, noise_dps=noise_dps)
    return WEARABLES[model](source, seed=seed, speed=speed, name=name, rate_hz=rate_hz)
