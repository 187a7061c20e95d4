"""The simulated wearables the service can run in its own process (`gyrocal serve --mock N`), offered to it
through the ``gyrocal.simulators`` entry point: the service knows only this module's names, never the
classes behind them."""

from __future__ import annotations

from collections.abc import Callable

from calib.simulator.kit import TrayFaults
from wearable_protocol.models import model as device_model

from .follower import KitFollower, SessionFollower
from .hand import HANDS
from .prompted import PromptedSource
from .scenarios import SCENARIOS
from .sources import SampleSource, ScriptedSource
from .vendors import WEARABLES
from .wearable import Wearable

HAND_PREFIX = "hand:"
# the scripted clinicians, then those who follow the session's prompts (hand:careful, hand:bumps, ...)
scenarios: tuple[str, ...] = (*SCENARIOS, *(HAND_PREFIX + h for h in HANDS))
models: tuple[str, ...] = tuple(WEARABLES)


def rates_instead(model: str, rate_hz: float) -> str | None:
    """None when a simulated wearable of ``model`` offers ``rate_hz``; else the rates it does offer, in words."""
    m = device_model(model)
    return None if m.offers_rate(rate_hz) else m.rates_text()


def wearable(*, seed: int, scenario: str, speed: float, name: str, rate_hz: float | None, noise_dps: float,
             model: str = "gyrocal", service_url: Callable[[], str | None] | None = None) -> Wearable:
    """A simulated wearable speaking ``model``'s protocol whose clinician performs ``scenario`` whenever
    streaming starts. A ``hand:<style>`` clinician follows the prompts of the wearable's sessions on the
    service at ``service_url()``, reading its events over HTTP as the page does."""
    source: SampleSource
    if scenario.startswith(HAND_PREFIX):
        prompted = PromptedSource(seed=seed, hand=scenario[len(HAND_PREFIX):], noise_dps=noise_dps)
        prompted.streaming = SessionFollower(name, prompted.observe_now, service_url or (lambda: None)).start().wake
        source = prompted
    else:
        source = ScriptedSource(seed=seed, scenario=scenario, noise_dps=noise_dps)
    return WEARABLES[model](source, seed=seed, speed=speed, name=name, rate_hz=rate_hz)


def kit(*, seed: int, n: int, speed: float, names: list[str], rate_hz: float | None, noise_dps: float,
        model: str = "gyrocal", faults: TrayFaults | None = None, hand: str | None = None,
        service_url: Callable[[], str | None] | None = None) -> list[Wearable]:
    """``n`` simulated wearables speaking ``model``'s protocol, riding in one tray that one clinician turns through the
    protocol whenever their streams start: a scripted one (``mock_device.kit``), or with ``hand`` a ``hand:<style>``
    clinician who follows the prompts of the kit session that holds wearables of the tray on the service at
    ``service_url()`` (``mock_device.prompted_kit``). ``faults`` (``calib.simulator.kit.TrayFaults``): the wearable that
    slips in its slot, the one whose link drops (scripted clinician only), the one beside the tray, and how far the
    sensors' axes are from orthogonal (``mock_device.kit``)."""
    from .kit import KitSource, Tray
    from .prompted_kit import PromptedKitSource, PromptedTray

    sources: list[SampleSource]
    if hand is not None:
        prompted = PromptedTray(seed, n, hand.removeprefix(HAND_PREFIX), noise_dps=noise_dps, faults=faults)
        follower = KitFollower(names, prompted.observe, service_url or (lambda: None)).start()
        in_tray = [PromptedKitSource(prompted, i) for i in range(n)]
        for one in in_tray:
            one.streaming = follower.wake
        sources = list(in_tray)
    else:
        tray = Tray(seed, n, noise_dps=noise_dps, faults=faults)
        sources = [KitSource(tray, i) for i in range(n)]
    return [WEARABLES[model](source, seed=seed * 1000 + i + 1, speed=speed, name=names[i], rate_hz=rate_hz)
            for i, source in enumerate(sources)]
