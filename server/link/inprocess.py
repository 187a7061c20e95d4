"""The in-process transport: a peripheral object in this process (the simulated wearable) behind the
same interface as BLE, for fast tests and ``gyrocal serve --mock``. No D-Bus, no radio."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

from wearable_protocol import (
    ConnectionDropped,
    GattError,
    GattPeripheral,
    PeripheralUnavailable,
)
from wearable_protocol.models import identify

from .base import (
    ConnectError,
    DeviceNotFoundError,
    DiscoveredDevice,
    LinkError,
    ReconnectPolicy,
)
from .core import LinkCore

ADVERTISING_POLL_S = 0.05


class _Central:
    def __init__(self, link: InProcessLink) -> None:
        self.link = link
        self.active = True

    def notify(self, char_uuid: str, value: bytes) -> None:
        if self.active:
            cb = self.link._callbacks.get(char_uuid)
            if cb is not None:
                cb(bytes(value))

    def link_lost(self) -> None:
        if self.active:
            self.active = False
            self.link._on_link_lost()


class InProcessLink(LinkCore):
    """A :class:`~wearable_protocol.GattPeripheral` in this process, as a WearableLink."""

    def __init__(self, peripheral: GattPeripheral, *, reconnect: ReconnectPolicy | None = None,
                 command_timeout_s: float = 5.0, scan_timeout_s: float = 5.0, model: str | None = None,
                 clock: Callable[[], float] | None = None) -> None:
        super().__init__(peripheral.address, reconnect=reconnect, command_timeout_s=command_timeout_s, model=model,
                         clock=clock)
        self.peripheral = peripheral
        self.name = peripheral.name
        self.scan_timeout_s = scan_timeout_s
        self._central: _Central | None = None
        self._callbacks: dict[str, Callable[[bytes], None]] = {}
        self._chars = {c.uuid for s in peripheral.services for c in s.characteristics}

    async def scan(self, timeout: float = 5.0) -> list[DiscoveredDevice]:
        deadline = time.monotonic() + timeout
        while True:
            if self.peripheral.advertising:
                found = identify(self.peripheral.name, self.peripheral.advertised_services)
                return [DiscoveredDevice(self.peripheral.address, self.peripheral.name, -50, found.key if found else None)]
            if time.monotonic() >= deadline:
                return []
            await asyncio.sleep(ADVERTISING_POLL_S)

    async def _t_connect(self) -> None:
        if not await self.scan(self.scan_timeout_s):
            raise DeviceNotFoundError(
                f"wearable {self.address} was not found within {self.scan_timeout_s:g} s: "
                "check that it is switched on, in range and not connected elsewhere")
        central = _Central(self)
        self._callbacks = {}
        try:
            self.peripheral.connect(central)
        except ConnectionDropped as e:
            raise ConnectError(f"the link to {self.address} dropped during connection setup ({e})") from e
        except PeripheralUnavailable as e:
            raise ConnectError(f"connecting to {self.address} failed: {e}") from e
        self._central = central
        await asyncio.sleep(0)

    async def _t_disconnect(self) -> None:
        central, self._central = self._central, None
        if central is not None and central.active:
            central.active = False
            self.peripheral.disconnect()

    def _t_has(self, char_uuid: str) -> bool:
        return char_uuid in self._chars

    def _live(self) -> None:
        if self._central is None or not self._central.active:
            raise LinkError("the wearable is not connected")

    async def _t_read(self, char_uuid: str) -> bytes:
        self._live()
        try:
            return bytes(self.peripheral.read(char_uuid))
        except GattError as e:
            raise LinkError(f"reading {char_uuid} failed: {e}") from e

    async def _t_write(self, char_uuid: str, data: bytes, *, response: bool = True) -> None:
        self._live()
        try:
            self.peripheral.write(char_uuid, bytes(data))
        except GattError as e:
            raise LinkError(f"writing {char_uuid} failed: {e}") from e
        await asyncio.sleep(0)

    async def _t_subscribe(self, char_uuid: str, callback: Callable[[bytes], None]) -> None:
        self._live()
        self._callbacks[char_uuid] = callback
        self.peripheral.set_notify(char_uuid, True)

    async def _t_unsubscribe(self, char_uuid: str) -> None:
        self._callbacks.pop(char_uuid, None)
        if self._central is not None and self._central.active:
            self.peripheral.set_notify(char_uuid, False)
