"""The wearables the service knows: simulated ones in this process (--mock) and BLE ones (--ble).

A device's id is "mock-N" for a simulated wearable and its Bluetooth address for a BLE one. Each
device owns one link (server.link) that the guided sessions use one at a time.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import TYPE_CHECKING, Any, Protocol, TypedDict

from calib.apply.identity import SensorIdentity
from calib.extras import install_hint
from wearable_protocol.models import MODELS, LossDetection, TimeStamps

from .link.base import DeviceInfo, DiscoveredDevice
from .link.slots import AdapterSlots

if TYPE_CHECKING:  # the simulator's numerics load only with simulated wearables
    from calib.simulator.kit import TrayFaults

log = logging.getLogger(__name__)

DEVICE_ID_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._:-]{0,127}$")
SIMULATORS_GROUP = "gyrocal.simulators"


class Simulators(Protocol):
    """What a package of simulated wearables offers the service (mock_device.simulators, through the
    ``gyrocal.simulators`` entry point): its scenarios, its models and their rates, and a wearable (a GATT
    peripheral)."""

    scenarios: tuple[str, ...]
    models: tuple[str, ...]

    def rates_instead(self, model: str, rate_hz: float) -> str | None:
        """None when a simulated wearable of ``model`` offers ``rate_hz``; else the rates it offers, in words."""

    def wearable(self, *, seed: int, scenario: str, speed: float, name: str, rate_hz: float | None, noise_dps: float,
                 model: str, service_url: Callable[[], str | None]) -> Any: ...

    def kit(self, *, seed: int, n: int, speed: float, names: list[str], rate_hz: float | None, noise_dps: float,
            model: str, faults: TrayFaults | None, hand: str | None,
            service_url: Callable[[], str | None]) -> list[Any]: ...


class SimulatorsUnavailable(Exception):
    """No package of simulated wearables could be loaded; the message says which module failed and what installs it."""


def load_simulators() -> Simulators:
    """The installed simulated wearables; SimulatorsUnavailable, naming the reason, when none can be loaded."""
    failures: list[str] = []
    for ep in entry_points(group=SIMULATORS_GROUP):
        try:
            simulators: Simulators = ep.load()
            return simulators
        except ImportError as exc:
            failures.append(f"the simulated wearables of {ep.value} cannot be loaded: {install_hint(exc)}")
    if not failures:
        raise SimulatorsUnavailable("no package offers simulated wearables (the entry point group "
                                    f"{SIMULATORS_GROUP!r} is empty): reinstall gyrocal with pip install 'gyrocal[server,ble]'")
    raise SimulatorsUnavailable("; ".join(failures))


class ModelFacts(TypedDict):
    """What the page and the estimator need to know about a wearable model (the fields of the same names of GET
    /devices)."""

    model: str | None
    model_label: str | None
    sample_rate_hz: float | None
    gyro_full_scale_dps: int | None
    time_stamps: TimeStamps | None
    loss_detection: LossDetection | None
    limitations: list[str]
    write_back: bool
    identify: str | None  # what it does when asked which one it is ("blinks its light"); None: it cannot be asked


def model_facts(key: str | None, info: dict[str, Any] | None = None) -> ModelFacts:
    """What the page and the estimator need to know about a wearable model (see wearable_protocol.models)."""
    info = info or {}
    m = MODELS.get(key) if key else None
    if m is None:
        return {"model": key, "model_label": None, "sample_rate_hz": info.get("sample_rate_hz"),
                "gyro_full_scale_dps": info.get("gyro_full_scale_dps"), "time_stamps": None, "loss_detection": None,
                "limitations": [], "write_back": False, "identify": None}
    return {"model": m.key, "model_label": m.label, "sample_rate_hz": info.get("sample_rate_hz") or m.stream_rate_hz,
            "gyro_full_scale_dps": info.get("gyro_full_scale_dps") or m.gyro_range_dps, "time_stamps": m.time_stamps,
            "loss_detection": m.loss_detection, "limitations": list(m.limitations()),
            "write_back": bool(info.get("write_back", m.write_back)), "identify": m.identify}


def sensor_identity(device_id: str, info: DeviceInfo) -> SensorIdentity:
    """The sensor a connected wearable described, with its power-up and temperature when it reports them."""
    p = info.power_up
    return SensorIdentity(device_id=device_id, sensor_model=info.model, serial=info.serial, firmware=info.firmware,
                          boot_count=p.boot_count if p else None, booted_at=p.booted_at if p else None,
                          temperature_c=p.temperature_c if p else None)


@dataclass
class Device:
    """A wearable the service can stream from."""

    id: str
    transport: str  # "inprocess" | "ble"
    name: str | None
    address: str | None
    make_link: Callable[[], Any]
    model: str | None = None  # the protocol it speaks (wearable_protocol.models), when known
    simulated: bool = False
    scenario: str | None = None
    peripheral: Any = None  # the simulated wearable object (in-process only)
    link: Any = None
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def connected(self) -> bool:
        return bool(self.link is not None and getattr(self.link, "connected", False))

    def model_facts(self) -> ModelFacts:
        """The device's model, the rate and range it streams at (read from it once connected, else the model's
        choice) and what its protocol cannot tell."""
        return model_facts(self.info.get("model") or self.model, self.info)

    @property
    def simulated_identifying(self) -> bool | None:
        """Whether a simulated wearable's light blinks now (None for real hardware)."""
        return None if self.peripheral is None else bool(getattr(self.peripheral, "identifying", False))

    @property
    def simulated_truth(self) -> dict[str, Any] | None:
        """The simulated sensor's true {k, b} and, where the simulation has one, its full K (None for real hardware)."""
        if self.peripheral is None:
            return None
        truth = getattr(self.peripheral, "truth", None)
        if not truth:
            return None
        out: dict[str, Any] = {"k": [float(v) for v in truth["k"]], "b": [float(v) for v in truth["b"]]}
        if truth.get("K") is not None:
            out["K"] = [[float(v) for v in row] for row in truth["K"]]
        return out

    def read_local_battery(self) -> None:
        """Note the battery level of a wearable simulated in this process: it answers the read at once,
        without a connection, so the device list shows it before the first session (a BLE device's
        level is read when a session connects)."""
        if self.peripheral is None:
            return
        import wearable_protocol as wp

        try:
            raw = bytes(self.peripheral.read(wp.BATTERY_LEVEL_CHAR))
        except wp.GattError:  # a peripheral without a battery service: the level stays unknown
            return
        if raw:
            self.info["battery_pct"] = int(raw[0])

    async def note_held(self, link: Any, store: Any) -> None:
        """Ask the connected wearable which calibration it holds and record the answer in ``store`` (when it can hold
        one). A failed read or store write is only logged: nothing waits on it."""
        self.info["write_back"] = bool(link.holds_calibrations)
        if not link.holds_calibrations:
            return
        try:
            held = await link.held_calibration()
            await asyncio.to_thread(store.record_held, self.id, held.calibration_id if held else None)
        except Exception as exc:
            log.info("what %s holds was not recorded: %s", self.id, exc)

    def get_link(self) -> Any:
        if self.link is None:
            self.link = self.make_link()
        return self.link

    async def close(self) -> None:
        link = self.link
        if link is not None:
            with contextlib.suppress(Exception):
                await link.disconnect()
        if self.peripheral is not None and hasattr(self.peripheral, "aclose"):
            with contextlib.suppress(Exception):
                await self.peripheral.aclose()


@dataclass(frozen=True)
class ScaledClock:
    """The monotonic clock on a simulated wearable's time scale: ``scale`` times real time (a link's ``clock``; the
    session reads ``scale`` to put real-time allowances on it)."""

    scale: float

    def __call__(self) -> float:
        import time

        return time.monotonic() * self.scale


class DeviceManager:
    """Known devices, by id; scanning adds BLE ones."""

    def __init__(self, ble: bool = False, ble_adapters: Sequence[str] = ("hci0",), ble_slots: int = 5,
                 ble_time_scale: float = 1.0) -> None:
        self.devices: dict[str, Device] = {}
        self.ble = ble
        # the clock BLE links time arrivals by, on the wearables' time scale (simulated ones may run faster)
        self.ble_clock: Callable[[], float] | None = (
            None if ble_time_scale == 1.0 else ScaledClock(float(ble_time_scale)))
        self.ble_adapters = tuple(ble_adapters)
        self.slots = AdapterSlots(self.ble_adapters, ble_slots)  # shared by every BLE link of the service
        # where the service answers, once it listens: simulated clinicians who follow the prompts read it there
        self.service_url: str | None = None

    def get(self, device_id: str) -> Device | None:
        return self.devices.get(device_id)

    def add(self, device: Device) -> Device:
        self.devices[device.id] = device
        return device

    def add_mocks(
        self,
        simulators: Simulators,
        n: int,
        speed: float = 1.0,
        seed: int = 0,
        scenarios: list[str] | None = None,
        rate_hz: float | None = None,
        noise_dps: float = 0.03,
        model: str = "gyrocal",
        first: int = 1,
        kit: bool = False,
        faults: TrayFaults | None = None,
    ) -> list[Device]:
        """N simulated wearables mock-``first`` … mock-(first+N-1) speaking ``model``'s protocol, each performing its
        scenario when streaming starts. ``rate_hz`` None: the model's streaming rate. A wearable's number alone sets
        its sensor, so two gateways simulating mock-8 simulate the same wearable. ``kit``: the N ride in one tray that
        one clinician turns, instead of each its scenario: a scripted one, or the ``hand:<style>`` clinician of
        ``scenarios`` who follows the kit's prompts; ``faults``: what goes wrong in the tray (a wearable loose in its
        slot, one whose link drops, one beside the tray, axes not orthogonal: ``calib.simulator.kit.TrayFaults``)."""

        from .link import InProcessLink, ReconnectPolicy

        device_clock = ScaledClock(float(speed))  # arrival times on the simulated wearables' time scale

        scenarios = scenarios or ["normal"]
        ids = [f"mock-{i}" for i in range(first, first + n)]
        tray: list[Any] = []
        hand = next((s for s in scenarios if s.startswith("hand:")), None) if kit else None
        if kit:
            tray = simulators.kit(seed=seed * 1000 + first, n=n, speed=speed, names=ids, rate_hz=rate_hz, noise_dps=noise_dps,
                                  model=model, faults=faults, hand=hand, service_url=lambda: self.service_url)
        added = []
        for j, i in enumerate(range(first, first + n)):
            scenario = (f"kit:{hand}" if hand else "kit") if kit else scenarios[(i - 1) % len(scenarios)]
            dev_seed = seed * 1000 + i
            wearable = tray[j] if kit else simulators.wearable(
                seed=dev_seed, scenario=scenario, speed=speed, name=f"mock-{i}", rate_hz=rate_hz, noise_dps=noise_dps,
                model=model, service_url=lambda: self.service_url)
            # the reconnection backoff runs on wall time: scale it with the simulated clock
            policy = ReconnectPolicy(initial_delay_s=0.25 / speed, max_delay_s=max(0.05, 5.0 / speed), timeout_s=60.0)
            dev = Device(
                id=f"mock-{i}",
                transport="inprocess",
                name=wearable.name,
                address=wearable.address,
                make_link=functools.partial(InProcessLink, wearable, reconnect=policy, scan_timeout_s=5.0, model=model,
                                            clock=device_clock),
                model=model,
                simulated=True,
                scenario=scenario,
                peripheral=wearable,
            )
            dev.read_local_battery()
            added.append(self.add(dev))
        return added

    async def scan(self, timeout_s: float = 5.0) -> list[Device]:
        """Scan for wearables: BLE ones when --ble, and the simulated ones (always "found")."""
        found: list[Device] = [d for d in self.devices.values() if d.transport == "inprocess"]
        for dev in found:
            dev.read_local_battery()
        if self.ble:
            from .link.ble import BleLink

            for disc in await self._scan_adapters(timeout_s):
                known = self.devices.get(disc.address)
                if known is None:
                    known = self.add(
                        Device(
                            id=disc.address,
                            transport="ble",
                            name=disc.name,
                            address=disc.address,
                            make_link=functools.partial(BleLink, disc.address, slots=self.slots, model=disc.model,
                                                              clock=self.ble_clock),
                            model=disc.model,
                        )
                    )
                known.info["rssi"] = disc.rssi
                if disc.name:
                    known.name = disc.name
                found.append(known)
        return found

    async def _scan_adapters(self, timeout_s: float) -> list[DiscoveredDevice]:
        """What every adapter sees, each wearable once (at its strongest signal); an adapter that fails is skipped
        while another one answers."""
        from .link.base import by_signal
        from .link.ble import BleLink

        results = await asyncio.gather(*(BleLink(adapter=a).scan(timeout_s) for a in self.ble_adapters), return_exceptions=True)
        errors = [r for r in results if isinstance(r, BaseException)]
        if len(errors) == len(results):
            raise errors[0]
        for adapter, r in zip(self.ble_adapters, results, strict=True):
            if isinstance(r, BaseException):
                log.warning("Bluetooth adapter %s could not scan: %s", adapter, r)
        best: dict[str, DiscoveredDevice] = {}
        for disc in by_signal(d for r in results if not isinstance(r, BaseException) for d in r):
            best.setdefault(disc.address, disc)  # the strongest sighting of each wearable
        return list(best.values())

    def add_ble_address(self, address: str) -> Device:
        """A BLE wearable known by address (from the store) that has not been scanned yet."""
        from .link.ble import BleLink

        dev = self.devices.get(address)
        if dev is None:
            dev = self.add(
                Device(
                    id=address,
                    transport="ble",
                    name=None,
                    address=address,
                    make_link=functools.partial(BleLink, address, slots=self.slots, clock=self.ble_clock),
                )
            )
        return dev

    async def close(self) -> None:
        for dev in self.devices.values():
            await dev.close()
