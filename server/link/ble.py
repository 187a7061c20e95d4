"""The bleak transport: the wearable over Bluetooth LE (BlueZ on Linux, or the simulated BlueZ).

bleak reaches BlueZ on the D-Bus system bus; point ``DBUS_SYSTEM_BUS_ADDRESS`` at the simulated
BlueZ's private bus (``gyrocal mock-device --ble`` prints it) to use a simulated wearable.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable
from typing import Any

from wearable_protocol.models import MODELS, identify

from .base import (
    ConnectError,
    DeviceNotFoundError,
    DiscoveredDevice,
    LinkError,
    ReconnectPolicy,
    by_signal,
    connect_gave_up,
)
from .core import LinkCore
from .slots import AdapterSlots, OutOfConnectionSlots

log = logging.getLogger(__name__)


def _bleak() -> Any:
    try:
        import bleak
    except ImportError as e:  # the "ble" extra is not installed
        raise LinkError("Bluetooth support is not installed: pip install 'gyrocal[ble]'") from e
    return bleak


def _model_of(device: Any, adv: Any) -> str | None:
    found = identify(adv.local_name or device.name, list(adv.service_uuids))
    return found.key if found else None


async def _connect(bleak: Any, device: Any, on_disconnect: Callable[[Any], None], attempts: int) -> Any:
    """A connected BleakClient, through bleak-retry-connector; its errors as LinkErrors that say what to do."""
    import bleak_retry_connector as brc

    name = device.name or device.address
    try:
        return await brc.establish_connection(bleak.BleakClient, device, name, disconnected_callback=on_disconnect,
                                              max_attempts=attempts)
    except brc.BleakOutOfConnectionSlotsError as e:
        raise OutOfConnectionSlots(f"the Bluetooth adapter has no free connection slot for {device.address} ({e}); end a "
                                   "session on another wearable or add another adapter to --ble-adapter") from e
    except brc.BleakNotFoundError as e:
        raise DeviceNotFoundError(f"wearable {device.address} disappeared while connecting ({e}); move it closer and "
                                  "check it is not connected to another phone or computer") from e
    except (TimeoutError, bleak.exc.BleakError, OSError) as e:  # bleak-retry-connector has retried already
        raise connect_gave_up(device.address, attempts, e or type(e).__name__) from e


class BleLink(LinkCore):
    """A wearable over BLE via bleak. ``address`` None: connect() takes the first supported wearable that
    answers (of ``model``, when given). ``adapter``: the Bluetooth adapter (hci0, hci1, ...); ``slots``: the
    service's adapters and their connection slots (then the adapter with the most free slots is used)."""

    def __init__(self, address: str | None = None, *, adapter: str | None = None, scan_timeout_s: float = 5.0,
                 reconnect: ReconnectPolicy | None = None,
                 command_timeout_s: float = 5.0, model: str | None = None,
                 clock: Callable[[], float] | None = None, slots: AdapterSlots | None = None) -> None:
        super().__init__(address.upper() if address else None, reconnect=reconnect, command_timeout_s=command_timeout_s,
                         model=model, clock=clock)
        self.adapter = adapter
        self.slots = slots
        self.scan_timeout_s = scan_timeout_s
        self._client: Any = None
        self._device: Any = None

    def _bluez_args(self) -> dict[str, Any]:
        return {"adapter": self.adapter} if self.adapter else {}

    async def scan(self, timeout: float = 5.0) -> list[DiscoveredDevice]:
        """Wearables of the supported models (by advertised service or name), strongest signal first.

        The scan is unfiltered (Polar sensors advertise no service of their own, only a name), so BlueZ
        reports every advertiser and the ones gyrocal cannot speak to are left out here."""
        bleak = _bleak()
        try:
            found = await bleak.BleakScanner.discover(timeout=timeout, return_adv=True, bluez=self._bluez_args())
        except bleak.exc.BleakError as e:
            raise LinkError(f"Bluetooth scan failed: {e}") from e
        devices = [DiscoveredDevice(d.address, a.local_name or d.name, a.rssi, _model_of(d, a)) for d, a in found.values()]
        wanted = [d for d in devices if d.model is not None and (self.model_key is None or d.model == self.model_key)]
        return by_signal(wanted)

    async def _find(self, bleak: Any, adapter: str | None) -> Any:
        """The wearable as ``adapter`` sees it (None: not found there)."""
        bluez = {"adapter": adapter} if adapter else {}
        try:
            if self.address is None:
                wanted = (self.model_key,) if self.model_key else tuple(MODELS)
                return await bleak.BleakScanner.find_device_by_filter(lambda d, adv: _model_of(d, adv) in wanted,
                                                                      timeout=self.scan_timeout_s, bluez=bluez)
            return await bleak.BleakScanner.find_device_by_address(self.address, timeout=self.scan_timeout_s, bluez=bluez)
        except bleak.exc.BleakError as e:
            raise ConnectError(f"Bluetooth scan failed: {e}") from e

    async def _t_connect(self) -> None:
        """Find the wearable on the adapter with the most free connection slots, take a slot there, and connect with
        bleak-retry-connector (BlueZ-aware retries and backoff, stale connections closed first)."""
        bleak = _bleak()
        adapters: list[str | None] = list(await self.slots.by_free_slots()) if self.slots else [self.adapter]
        device = None
        seen = False
        failures: list[ConnectError] = []
        for adapter in adapters:
            try:
                found = await self._find(bleak, adapter)
            except ConnectError as e:  # this adapter cannot scan (unplugged, powered off): try the next one
                log.warning("Bluetooth adapter %s: %s", adapter, e)
                failures.append(e)
                continue
            if found is None:
                continue
            seen = True
            if self.slots is None or await self.slots.allocate(found):
                device, self.adapter = found, adapter
                break
        if device is None:
            if seen and self.slots is not None:
                raise OutOfConnectionSlots(await self.slots.full_message())
            if len(failures) == len(adapters):
                raise failures[0]
            which = f"wearable {self.address} was not found" if self.address else "no supported wearable was found"
            raise DeviceNotFoundError(
                f"{which} within {self.scan_timeout_s:g} s: "
                "check that it is switched on, in range and not connected elsewhere")
        self.address = device.address.upper()
        self._device = device
        try:
            self._client = await _connect(bleak, device, self._disconnected, self.policy.connect_attempts)
        except LinkError:
            if self.slots is not None:
                await self.slots.release(device)
            raise
        self.name = device.name

    def _disconnected(self, client: Any) -> None:
        if client is self._client:
            self._on_link_lost()

    async def _t_disconnect(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            with contextlib.suppress(Exception):
                await client.disconnect()
        if self.slots is not None and self._device is not None:
            await self.slots.release(self._device)

    def _t_has(self, char_uuid: str) -> bool:
        services = self._client.services if self._client is not None else None
        return services is not None and services.get_characteristic(char_uuid) is not None

    def _live(self) -> Any:
        if self._client is None or not self._client.is_connected:
            raise LinkError("the wearable is not connected")
        return self._client

    async def _t_read(self, char_uuid: str) -> bytes:
        return bytes(await self._live().read_gatt_char(char_uuid))

    async def _t_write(self, char_uuid: str, data: bytes, *, response: bool = True) -> None:
        await self._live().write_gatt_char(char_uuid, data, response=response)

    async def _t_subscribe(self, char_uuid: str, callback: Callable[[bytes], None]) -> None:
        await self._live().start_notify(char_uuid, lambda _char, value: callback(value))

    async def _t_unsubscribe(self, char_uuid: str) -> None:
        with contextlib.suppress(Exception):
            await self._live().stop_notify(char_uuid)
