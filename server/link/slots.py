"""The connection slots of the service's Bluetooth adapters.

A BlueZ adapter holds only a few connections at once: 5 on CSR chips, 7 on Broadcom ones (as measured by
bleak-retry-connector's authors, its pull request #67); past that, a connection attempt fails in ways that
look like an out-of-range device. The service therefore counts its connections per adapter with
bleak-retry-connector's ``BleakSlotManager`` (which follows BlueZ's own Connected properties), connects
through the adapter with the most free slots, and says plainly when all are in use.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from .base import ConnectError

DEFAULT_SLOTS_PER_ADAPTER = 5  # the smaller of the common limits (CSR 5, Broadcom 7)


class OutOfConnectionSlots(ConnectError):
    """Every adapter the service may use holds as many connections as it can."""

    retryable = False


class AdapterSlots:
    """The adapters (``hci0``, ``hci1``, …) a service may connect through and their slots; one per service."""

    def __init__(self, adapters: Sequence[str] = ("hci0",), slots_per_adapter: int = DEFAULT_SLOTS_PER_ADAPTER) -> None:
        if not adapters:
            raise ValueError("name at least one Bluetooth adapter")
        if slots_per_adapter < 1:
            raise ValueError("an adapter has at least one connection slot")
        self.adapters = tuple(adapters)
        self.slots_per_adapter = int(slots_per_adapter)
        self._manager: Any = None

    async def manager(self) -> Any:
        """bleak-retry-connector's slot manager, set up on first use (it follows bleak's BlueZ manager)."""
        if self._manager is None:
            from bleak_retry_connector import BleakSlotManager

            manager = BleakSlotManager()
            await manager.async_setup()
            for adapter in self.adapters:
                manager.register_adapter(adapter, self.slots_per_adapter)
            self._manager = manager
        return self._manager

    async def by_free_slots(self) -> list[str]:
        """The adapters, the one with the most free slots first."""
        manager = await self.manager()
        return sorted(self.adapters, key=lambda a: -manager.get_allocations(a).free)

    async def allocate(self, device: Any) -> bool:
        """Take a slot on the adapter that sees ``device`` (a bleak BLEDevice); False when it has none free."""
        return bool((await self.manager()).allocate_slot(device))

    async def release(self, device: Any) -> None:
        """Give the slot back once the device is disconnected."""
        (await self.manager()).release_slot(device)

    async def full_message(self) -> str:
        manager = await self.manager()
        held = {a: manager.get_allocations(a).allocated for a in self.adapters}
        which = "; ".join(f"{a}: {', '.join(held[a]) or 'none'}" for a in self.adapters)
        more = "add another adapter to --ble-adapter" if len(self.adapters) == 1 else "add another adapter"
        return (f"every Bluetooth adapter of this service is using its {self.slots_per_adapter} connection slots ({which}); "
                f"end a session on one of those wearables, or {more} (a BlueZ adapter holds 5 to 7 connections)")
