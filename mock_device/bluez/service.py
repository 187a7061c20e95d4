"""The org.bluez object tree on the bus: the adapter, a device per simulated peripheral once discovery runs,
and its GATT database while connected, with notifications as PropertiesChanged."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Collection, Iterable
from typing import Any

import numpy as np
from dbus_fast import BusType, Message, MessageType, Variant
from dbus_fast.aio import MessageBus
from dbus_fast.constants import RequestNameReply

from wearable_protocol import (
    CCCD_DESCRIPTOR,
    USER_DESCRIPTION_DESCRIPTOR,
    GattError,
    GattPeripheral,
)

from . import names as N
from .bus import BusUnavailable
from .methods import BlueZMethods
from .objects import Char, Device, device_path, variant

log = logging.getLogger(__name__)


class SimulatedBlueZ(BlueZMethods):
    """The ``org.bluez`` service on a (private) bus, serving the given peripherals.

    ``hide_services``: service UUIDs not exposed over GATT (as some BlueZ versions hide Device
    Information or claim Battery). ``battery_interface``: also expose ``org.bluez.Battery1`` on
    devices that have a battery level. Runs in the event loop it is started in.
    """

    def __init__(
        self,
        peripherals: Iterable[GattPeripheral],
        *,
        hide_services: Collection[str] = (),
        adapter_address: str = "00:1A:7D:DA:71:13",
        advert_interval_s: float = 0.1,
        connect_latency_s: float = 0.02,
        connect_fail_s: float = 0.3,
        seed: int = 0,
    ) -> None:
        self.devices: dict[str, Device] = {}
        for p in peripherals:
            path = device_path(p.address)
            if path in self.devices:
                raise ValueError(f"two peripherals have the address {p.address}")
            self.devices[path] = Device(p, path)
        self.hide_services = {u.lower() for u in hide_services}
        self.adapter_address = adapter_address
        self.advert_interval_s = advert_interval_s
        self.connect_latency_s = connect_latency_s
        self.connect_fail_s = connect_fail_s
        self._rng = np.random.default_rng([seed, 0xB1E2])
        self._bus: MessageBus | None = None
        self._objects: dict[str, dict[str, dict[str, Variant]]] = {}
        self._discovery: dict[str, dict[str, Any]] = {}  # sender -> filter of its running discovery
        self._pending_filters: dict[str, dict[str, Any]] = {}  # sender -> filter set before StartDiscovery
        self._tasks: set[asyncio.Task[Any]] = set()
        self._advertiser: asyncio.Task[None] | None = None

    # ------------------------------------------------------------------ lifecycle

    async def start(self, bus_address: str | None = None) -> None:
        """Connect to the bus (default: the system bus of DBUS_SYSTEM_BUS_ADDRESS) and own org.bluez."""
        bus = MessageBus(bus_address=bus_address) if bus_address else MessageBus(bus_type=BusType.SYSTEM)
        await bus.connect()
        reply = await bus.request_name(N.BLUEZ)
        if reply not in (RequestNameReply.PRIMARY_OWNER, RequestNameReply.ALREADY_OWNER):
            bus.disconnect()
            raise BusUnavailable(f"another process already owns {N.BLUEZ} on this bus")
        self._bus = bus
        bus.add_message_handler(self._on_message)
        await bus.call(Message(
            destination="org.freedesktop.DBus", path="/org/freedesktop/DBus", interface="org.freedesktop.DBus",
            member="AddMatch", signature="s",
            body=["type='signal',sender='org.freedesktop.DBus',member='NameOwnerChanged'"],
        ))
        self._objects["/org/bluez"] = {"org.bluez.AgentManager1": {}, "org.bluez.ProfileManager1": {}}
        self._objects[N.ADAPTER_PATH] = {N.ADAPTER: self._adapter_props()}
        self._advertiser = asyncio.get_running_loop().create_task(self._advertise())

    async def stop(self) -> None:
        """Disconnect every peripheral and leave the bus."""
        if self._advertiser is not None:
            self._advertiser.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._advertiser
            self._advertiser = None
        for dev in self.devices.values():
            if dev.connected:
                with contextlib.suppress(Exception):
                    dev.peripheral.disconnect()
                self._teardown(dev)
        for task in list(self._tasks):
            task.cancel()
        if self._bus is not None:
            self._bus.disconnect()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._bus.wait_for_disconnect(), 2)
            self._bus = None

    def _spawn(self, coro: Any) -> None:
        task = asyncio.get_running_loop().create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    # ------------------------------------------------------------------ objects and signals

    def _adapter_props(self) -> dict[str, Variant]:
        return {
            "Address": variant("s", self.adapter_address), "AddressType": variant("s", "public"),
            "Name": variant("s", "gyrocal-sim"), "Alias": variant("s", "gyrocal-sim"), "Class": variant("u", 0),
            "Powered": variant("b", True), "PowerState": variant("s", "on"), "Discoverable": variant("b", False),
            "DiscoverableTimeout": variant("u", 180), "Pairable": variant("b", True), "PairableTimeout": variant("u", 0),
            "Discovering": variant("b", False), "UUIDs": variant("as", []), "Modalias": variant("s", "usb:v1D6Bp0246d0548"),
            "Roles": variant("as", ["central", "peripheral"]),
        }

    def _device_props(self, dev: Device) -> dict[str, Variant]:
        p = dev.peripheral
        return {
            "Address": variant("s", p.address), "AddressType": variant("s", "random"), "Name": variant("s", p.name),
            "Alias": variant("s", p.name), "Adapter": variant("o", N.ADAPTER_PATH), "Paired": variant("b", False),
            "Bonded": variant("b", False), "Trusted": variant("b", False), "Blocked": variant("b", False),
            "LegacyPairing": variant("b", False), "Connected": variant("b", False), "ServicesResolved": variant("b", False),
            "UUIDs": variant("as", list(p.advertised_services)), "RSSI": variant("n", self._rssi()), "TxPower": variant("n", 0),
            "ManufacturerData": variant("a{qv}", {0xFFFF: variant("ay", b"gyrocal")}), "ServiceData": variant("a{sv}", {}),
        }

    def _rssi(self) -> int:
        return int(-58 + self._rng.integers(-4, 5))

    def _send(self, msg: Message) -> None:
        if self._bus is None or not self._bus.connected:
            return
        fut = self._bus.send(msg)
        fut.add_done_callback(lambda f: f.cancelled() or f.exception())

    def _add_object(self, path: str, interfaces: dict[str, dict[str, Variant]]) -> None:
        self._objects[path] = interfaces
        self._send(Message.new_signal("/", N.OBJECT_MANAGER, "InterfacesAdded", "oa{sa{sv}}", [path, interfaces]))

    def _remove_object(self, path: str) -> None:
        interfaces = self._objects.pop(path, None)
        if interfaces is not None:
            self._send(Message.new_signal("/", N.OBJECT_MANAGER, "InterfacesRemoved", "oas", [path, list(interfaces)]))

    def _set(self, path: str, interface: str, **changes: Variant) -> None:
        props = self._objects.get(path, {}).get(interface)
        if props is None:
            return
        props.update(changes)
        self._send(Message.new_signal(path, N.PROPERTIES, "PropertiesChanged", "sa{sv}as", [interface, changes, []]))

    # ------------------------------------------------------------------ discovery

    def _discovering(self) -> bool:
        return bool(self._discovery)

    def _wanted(self, dev: Device) -> bool:
        uuids = {u.lower() for u in dev.peripheral.advertised_services}
        for flt in self._discovery.values():
            wanted = flt.get("UUIDs")
            if not wanted or uuids & {u.lower() for u in wanted}:
                return True
        return False

    async def _advertise(self) -> None:
        while True:
            if self._discovering():
                for dev in self.devices.values():
                    if dev.connected or dev.connecting or not dev.peripheral.advertising or not self._wanted(dev):
                        continue
                    if dev.path not in self._objects:
                        self._add_object(dev.path, {N.DEVICE: self._device_props(dev)})
                    else:
                        self._set(dev.path, N.DEVICE, RSSI=variant("n", self._rssi()))
            await asyncio.sleep(self.advert_interval_s)

    def _set_discovering(self, sender: str, flt: dict[str, Any] | None) -> None:
        before = self._discovering()
        if flt is None:
            self._discovery.pop(sender, None)
        else:
            self._discovery[sender] = flt
        if before != self._discovering():
            self._set(N.ADAPTER_PATH, N.ADAPTER, Discovering=variant("b", self._discovering()))

    # ------------------------------------------------------------------ GATT database

    def _export_gatt(self, dev: Device) -> None:
        handle = 0x000A
        dev.chars.clear()
        dev.by_uuid.clear()
        dev.descs.clear()
        dev.gatt_paths.clear()
        for svc in dev.peripheral.services:
            if svc.uuid.lower() in self.hide_services:
                continue
            spath = f"{dev.path}/service{handle:04x}"
            handle += 1
            self._add_object(spath, {N.SERVICE: {
                "UUID": variant("s", svc.uuid), "Primary": variant("b", True), "Device": variant("o", dev.path),
                "Includes": variant("ao", []),
            }})
            dev.gatt_paths.append(spath)
            for spec in svc.characteristics:
                cpath = f"{spath}/char{handle:04x}"
                handle += 2  # declaration and value handles
                props = {
                    "UUID": variant("s", spec.uuid), "Service": variant("o", spath), "Value": variant("ay", b""),
                    "Flags": variant("as", list(spec.flags)), "MTU": variant("q", getattr(dev.peripheral, "mtu", 247)),
                }
                if "notify" in spec.flags or "indicate" in spec.flags:
                    props["Notifying"] = variant("b", False)
                self._add_object(cpath, {N.CHARACTERISTIC: props})
                char = Char(cpath, spec.uuid, spec)
                dev.chars[cpath] = char
                dev.by_uuid[spec.uuid] = char
                dev.gatt_paths.append(cpath)
                descs = []
                if "notify" in spec.flags or "indicate" in spec.flags:
                    descs.append((CCCD_DESCRIPTOR, ["read", "write"]))
                if spec.description:
                    descs.append((USER_DESCRIPTION_DESCRIPTOR, ["read"]))
                for duuid, dflags in descs:
                    dpath = f"{cpath}/desc{handle:04x}"
                    handle += 1
                    self._add_object(dpath, {N.DESCRIPTOR: {
                        "UUID": variant("s", duuid), "Characteristic": variant("o", cpath), "Value": variant("ay", b""),
                        "Flags": variant("as", dflags),
                    }})
                    dev.descs[dpath] = (char, duuid)
                    dev.gatt_paths.append(dpath)

    def _teardown(self, dev: Device) -> None:
        """The link is gone: remove the GATT objects, then lower ServicesResolved and Connected."""
        dev.connected = False
        for path in reversed(dev.gatt_paths):
            self._remove_object(path)
        dev.gatt_paths.clear()
        dev.chars.clear()
        dev.by_uuid.clear()
        dev.descs.clear()
        self._set(dev.path, N.DEVICE, ServicesResolved=variant("b", False))
        self._set(dev.path, N.DEVICE, Connected=variant("b", False))

    def _notify(self, dev: Device, char_uuid: str, value: bytes) -> None:
        char = dev.by_uuid.get(char_uuid)
        if char is None or not dev.connected:
            return
        props = self._objects[char.path][N.CHARACTERISTIC]
        props["Value"] = variant("ay", value)
        if char.notifying:
            self._send(Message.new_signal(char.path, N.PROPERTIES, "PropertiesChanged", "sa{sv}as",
                                          [N.CHARACTERISTIC, {"Value": props["Value"]}, []]))

    def _link_lost(self, dev: Device) -> None:
        if dev.connected:
            log.debug("link lost: %s", dev.path)
            self._teardown(dev)

    # ------------------------------------------------------------------ method calls

    def _on_message(self, msg: Message) -> Message | bool | None:
        if msg.message_type == MessageType.SIGNAL:
            if msg.member == "NameOwnerChanged" and len(msg.body) == 3 and not msg.body[2]:
                if msg.body[0] in self._discovery:
                    self._set_discovering(msg.body[0], None)
            return None
        if msg.message_type != MessageType.METHOD_CALL:
            return None
        path, iface, member = msg.path or "/", msg.interface, msg.member
        if iface == N.INTROSPECTABLE and member == "Introspect":
            return Message.new_method_return(msg, "s", [self._introspect(path)])
        if path == "/" and iface == N.OBJECT_MANAGER and member == "GetManagedObjects":
            return Message.new_method_return(msg, "a{oa{sa{sv}}}", [self._objects])
        if path not in self._objects:
            return Message.new_error(msg, N.ERR_UNKNOWN_OBJECT, f"no object at {path}")
        if iface == N.PROPERTIES:
            return self._properties_call(msg)
        handler = self._handlers().get((iface, member))
        if handler is None or iface not in self._objects[path]:
            return Message.new_error(msg, N.ERR_UNKNOWN_METHOD, f"{iface}.{member} is not a method of {path}")
        try:
            return handler(msg)
        except GattError as e:
            name = N.ERR_NOT_PERMITTED if e.code == "not_permitted" else N.ERR_FAILED
            return Message.new_error(msg, name, str(e))

    def _handlers(self) -> dict[tuple[str, str], Callable[[Message], Message | bool]]:
        return {
            (N.ADAPTER, "StartDiscovery"): self._start_discovery,
            (N.ADAPTER, "StopDiscovery"): self._stop_discovery,
            (N.ADAPTER, "SetDiscoveryFilter"): self._set_discovery_filter,
            (N.ADAPTER, "GetDiscoveryFilters"): lambda m: Message.new_method_return(
                m, "as", [["UUIDs", "RSSI", "Pathloss", "Transport", "DuplicateData", "Discoverable", "Pattern"]]),
            (N.ADAPTER, "RemoveDevice"): self._remove_device,
            (N.DEVICE, "Connect"): self._connect,
            (N.DEVICE, "Disconnect"): self._disconnect,
            (N.DEVICE, "Pair"): self._pair,
            (N.CHARACTERISTIC, "ReadValue"): self._read_char,
            (N.CHARACTERISTIC, "WriteValue"): self._write_char,
            (N.CHARACTERISTIC, "StartNotify"): self._start_notify,
            (N.CHARACTERISTIC, "StopNotify"): self._stop_notify,
            (N.CHARACTERISTIC, "AcquireNotify"): self._not_supported,
            (N.CHARACTERISTIC, "AcquireWrite"): self._not_supported,
            (N.DESCRIPTOR, "ReadValue"): self._read_desc,
            (N.DESCRIPTOR, "WriteValue"): lambda m: Message.new_error(m, N.ERR_NOT_PERMITTED, "Write not permitted"),
        }

    def _properties_call(self, msg: Message) -> Message:
        path = msg.path or "/"
        if msg.member == "GetAll":
            return Message.new_method_return(msg, "a{sv}", [self._objects[path].get(msg.body[0], {})])
        if msg.member == "Get":
            iface, name = msg.body
            props = self._objects[path].get(iface, {})
            if name not in props:
                return Message.new_error(msg, N.ERR_INVALID_ARGS, f"no property {iface}.{name} at {path}")
            return Message.new_method_return(msg, "v", [props[name]])
        if msg.member == "Set":
            iface, name, value = msg.body
            writable = {N.ADAPTER: {"Powered", "Alias", "Discoverable", "Pairable"}, N.DEVICE: {"Trusted", "Alias", "Blocked"}}
            if name not in writable.get(iface, set()) or iface not in self._objects[path]:
                return Message.new_error(msg, N.ERR_INVALID_ARGS, f"property {iface}.{name} cannot be set")
            self._set(path, iface, **{name: value})
            return Message.new_method_return(msg)
        return Message.new_error(msg, N.ERR_UNKNOWN_METHOD, f"{N.PROPERTIES}.{msg.member}")

    def _introspect(self, path: str) -> str:
        prefix = path.rstrip("/") + "/"
        children = sorted({p[len(prefix):].split("/")[0] for p in self._objects if p.startswith(prefix) and p != path})
        ifaces = list(self._objects.get(path, {}))
        if path == "/":
            ifaces.append(N.OBJECT_MANAGER)
        body = "".join(f'<interface name="{i}"/>' for i in ifaces + [N.PROPERTIES, N.INTROSPECTABLE])
        body += "".join(f'<node name="{c}"/>' for c in children)
        return f"<node>{body}</node>"

