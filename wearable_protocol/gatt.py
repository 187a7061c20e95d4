"""The GATT surface of a peripheral, independent of any Bluetooth stack.

A :class:`GattPeripheral` is what the simulated wearable implements. Two adapters put it on a link:
the simulated BlueZ (``mock_device.bluez``) exports it over D-Bus for the real bleak client, and the
in-process transport (``server.link.inprocess``) calls it directly. The peripheral reports back to
its connected central through the :class:`Central` callbacks.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable


@dataclass(frozen=True)
class CharacteristicSpec:
    """One characteristic: UUID, BlueZ flag names ("read", "write", "notify", ...) and an optional
    user description (exposed as a 0x2901 descriptor)."""

    uuid: str
    flags: tuple[str, ...]
    description: str | None = None


@dataclass(frozen=True)
class ServiceSpec:
    """One primary service and its characteristics; ``optional`` services are ones a host stack may
    hide (BlueZ claims Battery, some versions lock Device Information)."""

    uuid: str
    characteristics: tuple[CharacteristicSpec, ...]
    optional: bool = False


class PeripheralUnavailable(Exception):
    """The peripheral cannot be reached (out of range, not advertising): a connection attempt fails."""


class ConnectionDropped(PeripheralUnavailable):
    """The link came up and dropped again before the connection was set up (services not resolved)."""


class GattError(Exception):
    """A GATT request was refused: ``code`` is a short tag ('not_permitted', 'invalid_length', ...)."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


@runtime_checkable
class Central(Protocol):
    """What a peripheral may call on the central that is connected to it."""

    def notify(self, char_uuid: str, value: bytes) -> None:
        """Deliver a notification (only called while notifications are enabled on that characteristic)."""

    def link_lost(self) -> None:
        """The radio link dropped (the peripheral went out of range or reset)."""


@runtime_checkable
class GattPeripheral(Protocol):
    """A BLE peripheral seen through its GATT server."""

    address: str  # "AA:BB:CC:DD:EE:FF"
    name: str

    @property
    def advertising(self) -> bool:
        """In range and connectable."""

    @property
    def services(self) -> tuple[ServiceSpec, ...]:
        """The GATT database."""

    @property
    def advertised_services(self) -> tuple[str, ...]:
        """Service UUIDs in the advertisement."""

    def connect(self, central: Central) -> None:
        """A central connects; raises PeripheralUnavailable / ConnectionDropped when that fails."""

    def disconnect(self) -> None:
        """The central disconnects on purpose."""

    def read(self, char_uuid: str) -> bytes:
        """Value of a readable characteristic; raises GattError."""

    def write(self, char_uuid: str, data: bytes) -> None:
        """Write a characteristic; raises GattError."""

    def set_notify(self, char_uuid: str, enabled: bool) -> None:
        """Enable or disable notifications (the CCCD write)."""

