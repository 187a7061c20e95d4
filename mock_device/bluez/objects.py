"""The records behind the object tree: a device's path, the device and its characteristics."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

from dbus_fast import Variant

from wearable_protocol import (
    CharacteristicSpec,
    GattPeripheral,
)

from .names import (
    ADAPTER_PATH,
)


def device_path(address: str) -> str:
    return f"{ADAPTER_PATH}/dev_{address.upper().replace(':', '_')}"


@dataclass
class Char:
    path: str
    uuid: str
    spec: CharacteristicSpec
    notifying: bool = False


@dataclass
class Device:
    peripheral: GattPeripheral
    path: str
    connected: bool = False
    connecting: bool = False
    cancel_connect: bool = False
    announced: bool = False
    chars: dict[str, Char] = field(default_factory=dict)  # path -> char
    by_uuid: dict[str, Char] = field(default_factory=dict)
    descs: dict[str, tuple[Char, str]] = field(default_factory=dict)  # path -> (char, descriptor uuid)
    gatt_paths: list[str] = field(default_factory=list)  # in creation order


def variant(sig: str, value: Any) -> Variant:
    return Variant(sig, value)


class _Bus(Protocol):
    """What a connected peripheral's callbacks reach of the simulated BlueZ."""

    def _notify(self, dev: Device, char_uuid: str, value: bytes) -> None: ...

    def _link_lost(self, dev: Device) -> None: ...


class DeviceCentral:
    """The Central callbacks a peripheral gets while connected through the simulated BlueZ."""

    def __init__(self, bluez: _Bus, dev: Device) -> None:
        self._bluez = bluez
        self._dev = dev

    def notify(self, char_uuid: str, value: bytes) -> None:
        self._bluez._notify(self._dev, char_uuid, value)

    def link_lost(self) -> None:
        self._bluez._link_lost(self._dev)
