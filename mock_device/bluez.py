"""A simulated BlueZ: the ``org.bluez`` D-Bus service on a private bus, serving simulated peripherals.

bleak's Linux backend talks to BlueZ over the D-Bus system bus. This module starts a private
``dbus-daemon`` and publishes on it what bluetoothd would: an ObjectManager at ``/`` with an
adapter (``org.bluez.Adapter1`` at /org/bluez/hci0), a device per peripheral
(``org.bluez.Device1``) once discovery runs, and, while connected, the device's GATT database
(``GattService1``/``GattCharacteristic1``/``GattDescriptor1`` under
``/org/bluez/hci0/dev_XX_XX_XX_XX_XX_XX/serviceNNNN/charNNNN/descNNNN``, bleak parses the handles from
the paths). Notifications are ``PropertiesChanged`` of a characteristic's ``Value``, as BlueZ sends
them for ``StartNotify``. Any bleak program whose ``DBUS_SYSTEM_BUS_ADDRESS`` is the private bus's
address sees the peripherals as real devices.

What bleak checks and this provides: Adapter1 ``Powered`` and ``Roles`` containing "central";
Device1 ``Address``, ``Alias``, ``Adapter``, ``Connected``, ``ServicesResolved``, ``Paired``; devices
announced (InterfacesAdded, then RSSI updates) only while discovery runs; ``Connect`` raising
``Connected`` then, after the GATT objects are added, ``ServicesResolved``; ``Disconnect`` and link
loss lowering ``ServicesResolved`` and ``Connected`` and removing the GATT objects. bleak also runs
``bluetoothctl --version`` once per process; :func:`write_bluetoothctl_shim` provides one.
"""

from __future__ import annotations

import asyncio
import atexit
import contextlib
import ctypes
import logging
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from dbus_fast import BusType, Message, MessageType, Variant
from dbus_fast.aio import MessageBus
from dbus_fast.constants import RequestNameReply

from calib.errors import GyrocalError
from wearable_protocol import (
    CCCD_DESCRIPTOR,
    USER_DESCRIPTION_DESCRIPTOR,
    CharacteristicSpec,
    ConnectionDropped,
    GattError,
    GattPeripheral,
    PeripheralUnavailable,
)

log = logging.getLogger(__name__)

BLUEZ = "org.bluez"
ADAPTER_PATH = "/org/bluez/hci0"
OBJECT_MANAGER = "org.freedesktop.DBus.ObjectManager"
PROPERTIES = "org.freedesktop.DBus.Properties"
INTROSPECTABLE = "org.freedesktop.DBus.Introspectable"
ADAPTER = "org.bluez.Adapter1"
DEVICE = "org.bluez.Device1"
BATTERY = "org.bluez.Battery1"
SERVICE = "org.bluez.GattService1"
CHARACTERISTIC = "org.bluez.GattCharacteristic1"
DESCRIPTOR = "org.bluez.GattDescriptor1"
ERR_UNKNOWN_OBJECT = "org.freedesktop.DBus.Error.UnknownObject"
ERR_UNKNOWN_METHOD = "org.freedesktop.DBus.Error.UnknownMethod"
ERR_INVALID_ARGS = "org.freedesktop.DBus.Error.InvalidArgs"
ERR_FAILED = "org.bluez.Error.Failed"
ERR_IN_PROGRESS = "org.bluez.Error.InProgress"
ERR_NOT_PERMITTED = "org.bluez.Error.NotPermitted"
ERR_NOT_SUPPORTED = "org.bluez.Error.NotSupported"
ERR_NOT_CONNECTED = "org.bluez.Error.NotConnected"

BLUEZ_VERSION = "5.72"

_BUS_CONFIG = """<!DOCTYPE busconfig PUBLIC "-//freedesktop//DTD D-Bus Bus Configuration 1.0//EN"
 "http://www.freedesktop.org/standards/dbus/1.0/busconfig.dtd">
<busconfig>
  <type>session</type>
  <listen>unix:path={socket}</listen>
  <auth>EXTERNAL</auth>
  <policy context="default">
    <allow send_destination="*" eavesdrop="true"/>
    <allow eavesdrop="true"/>
    <allow own="*"/>
  </policy>
  <limit name="max_incoming_bytes">1000000000</limit>
  <limit name="max_outgoing_bytes">1000000000</limit>
  <limit name="max_message_size">1000000000</limit>
</busconfig>
"""


class BusUnavailable(GyrocalError):
    """The private D-Bus daemon could not be started."""


def _die_with_parent() -> None:
    """In the daemon child: get SIGTERM when the process that started it dies (Linux prctl)."""
    with contextlib.suppress(Exception):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


class PrivateBus:
    """A ``dbus-daemon`` on a private Unix socket, started and stopped by us.

    Use as a context manager or call :meth:`start` / :meth:`stop`. ``address`` is what to put in
    ``DBUS_SYSTEM_BUS_ADDRESS`` for bleak.
    """

    def __init__(self, workdir: str | os.PathLike[str] | None = None) -> None:
        self._own_dir = workdir is None
        self.workdir = Path(workdir) if workdir else None
        self.address: str | None = None
        self._proc: subprocess.Popen[bytes] | None = None

    def start(self) -> str:
        """Start the daemon; returns its address."""
        exe = shutil.which("dbus-daemon")
        if exe is None:
            raise BusUnavailable(
                "dbus-daemon is not installed: install the Debian package 'dbus' "
                "(sudo apt-get install dbus, or run scripts/install-system-deps.sh)"
            )
        if self.workdir is None:
            self.workdir = Path(tempfile.mkdtemp(prefix="gyrocal-dbus-"))
        self.workdir.mkdir(parents=True, exist_ok=True)
        config = self.workdir / "bus.conf"
        config.write_text(_BUS_CONFIG.format(socket=self.workdir / "system_bus_socket"))
        self._proc = subprocess.Popen(
            [exe, f"--config-file={config}", "--nofork", "--nopidfile", "--print-address=1"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
            preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None,
        )
        atexit.register(self.stop)
        assert self._proc.stdout is not None
        line = self._proc.stdout.readline().decode().strip()
        if not line:
            err = self._proc.stderr.read().decode() if self._proc.stderr else ""
            self.stop()
            raise BusUnavailable(f"dbus-daemon did not start: {err.strip() or 'no address printed'}")
        self.address = line
        return line

    def stop(self) -> None:
        """Stop the daemon and remove its socket and config (idempotent)."""
        proc, self._proc = self._proc, None
        if proc is not None and proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if proc is not None:
            for stream in (proc.stdout, proc.stderr):
                if stream is not None:
                    stream.close()
        if self._own_dir and self.workdir is not None:
            shutil.rmtree(self.workdir, ignore_errors=True)
            self.workdir = None
        self.address = None

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    def __enter__(self) -> PrivateBus:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def write_bluetoothctl_shim(directory: str | os.PathLike[str]) -> Path:
    """Write an executable ``bluetoothctl`` answering ``--version`` with 5.72 (bleak's version check);
    put ``directory`` first on PATH. Returns the directory."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    exe = d / "bluetoothctl"
    exe.write_text(f"#!/bin/sh\necho 'bluetoothctl: {BLUEZ_VERSION}'\n")
    exe.chmod(0o755)
    return d


def _device_path(address: str) -> str:
    return f"{ADAPTER_PATH}/dev_{address.upper().replace(':', '_')}"


@dataclass
class _Char:
    path: str
    uuid: str
    spec: CharacteristicSpec
    notifying: bool = False


@dataclass
class _Device:
    peripheral: GattPeripheral
    path: str
    connected: bool = False
    connecting: bool = False
    cancel_connect: bool = False
    announced: bool = False
    chars: dict[str, _Char] = field(default_factory=dict)  # path -> char
    by_uuid: dict[str, _Char] = field(default_factory=dict)
    descs: dict[str, tuple[_Char, str]] = field(default_factory=dict)  # path -> (char, descriptor uuid)
    gatt_paths: list[str] = field(default_factory=list)  # in creation order


class _DeviceCentral:
    """The Central callbacks a peripheral gets while connected through the simulated BlueZ."""

    def __init__(self, bluez: SimulatedBlueZ, dev: _Device) -> None:
        self._bluez = bluez
        self._dev = dev

    def notify(self, char_uuid: str, value: bytes) -> None:
        self._bluez._notify(self._dev, char_uuid, value)

    def link_lost(self) -> None:
        self._bluez._link_lost(self._dev)


def _v(sig: str, value: Any) -> Variant:
    return Variant(sig, value)


class SimulatedBlueZ:
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
        self.devices: dict[str, _Device] = {}
        for p in peripherals:
            path = _device_path(p.address)
            if path in self.devices:
                raise ValueError(f"two peripherals have the address {p.address}")
            self.devices[path] = _Device(p, path)
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
        reply = await bus.request_name(BLUEZ)
        if reply not in (RequestNameReply.PRIMARY_OWNER, RequestNameReply.ALREADY_OWNER):
            bus.disconnect()
            raise BusUnavailable(f"another process already owns {BLUEZ} on this bus")
        self._bus = bus
        bus.add_message_handler(self._on_message)
        await bus.call(Message(
            destination="org.freedesktop.DBus", path="/org/freedesktop/DBus", interface="org.freedesktop.DBus",
            member="AddMatch", signature="s",
            body=["type='signal',sender='org.freedesktop.DBus',member='NameOwnerChanged'"],
        ))
        self._objects["/org/bluez"] = {"org.bluez.AgentManager1": {}, "org.bluez.ProfileManager1": {}}
        self._objects[ADAPTER_PATH] = {ADAPTER: self._adapter_props()}
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
            "Address": _v("s", self.adapter_address), "AddressType": _v("s", "public"),
            "Name": _v("s", "gyrocal-sim"), "Alias": _v("s", "gyrocal-sim"), "Class": _v("u", 0),
            "Powered": _v("b", True), "PowerState": _v("s", "on"), "Discoverable": _v("b", False),
            "DiscoverableTimeout": _v("u", 180), "Pairable": _v("b", True), "PairableTimeout": _v("u", 0),
            "Discovering": _v("b", False), "UUIDs": _v("as", []), "Modalias": _v("s", "usb:v1D6Bp0246d0548"),
            "Roles": _v("as", ["central", "peripheral"]),
        }

    def _device_props(self, dev: _Device) -> dict[str, Variant]:
        p = dev.peripheral
        return {
            "Address": _v("s", p.address), "AddressType": _v("s", "random"), "Name": _v("s", p.name),
            "Alias": _v("s", p.name), "Adapter": _v("o", ADAPTER_PATH), "Paired": _v("b", False),
            "Bonded": _v("b", False), "Trusted": _v("b", False), "Blocked": _v("b", False),
            "LegacyPairing": _v("b", False), "Connected": _v("b", False), "ServicesResolved": _v("b", False),
            "UUIDs": _v("as", list(p.advertised_services)), "RSSI": _v("n", self._rssi()), "TxPower": _v("n", 0),
            "ManufacturerData": _v("a{qv}", {0xFFFF: _v("ay", b"gyrocal")}), "ServiceData": _v("a{sv}", {}),
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
        self._send(Message.new_signal("/", OBJECT_MANAGER, "InterfacesAdded", "oa{sa{sv}}", [path, interfaces]))

    def _remove_object(self, path: str) -> None:
        interfaces = self._objects.pop(path, None)
        if interfaces is not None:
            self._send(Message.new_signal("/", OBJECT_MANAGER, "InterfacesRemoved", "oas", [path, list(interfaces)]))

    def _set(self, path: str, interface: str, **changes: Variant) -> None:
        props = self._objects.get(path, {}).get(interface)
        if props is None:
            return
        props.update(changes)
        self._send(Message.new_signal(path, PROPERTIES, "PropertiesChanged", "sa{sv}as", [interface, changes, []]))

    # ------------------------------------------------------------------ discovery

    def _discovering(self) -> bool:
        return bool(self._discovery)

    def _wanted(self, dev: _Device) -> bool:
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
                        self._add_object(dev.path, {DEVICE: self._device_props(dev)})
                    else:
                        self._set(dev.path, DEVICE, RSSI=_v("n", self._rssi()))
            await asyncio.sleep(self.advert_interval_s)

    def _set_discovering(self, sender: str, flt: dict[str, Any] | None) -> None:
        before = self._discovering()
        if flt is None:
            self._discovery.pop(sender, None)
        else:
            self._discovery[sender] = flt
        if before != self._discovering():
            self._set(ADAPTER_PATH, ADAPTER, Discovering=_v("b", self._discovering()))

    # ------------------------------------------------------------------ GATT database

    def _export_gatt(self, dev: _Device) -> None:
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
            self._add_object(spath, {SERVICE: {
                "UUID": _v("s", svc.uuid), "Primary": _v("b", True), "Device": _v("o", dev.path), "Includes": _v("ao", []),
            }})
            dev.gatt_paths.append(spath)
            for spec in svc.characteristics:
                cpath = f"{spath}/char{handle:04x}"
                handle += 2  # declaration and value handles
                props = {
                    "UUID": _v("s", spec.uuid), "Service": _v("o", spath), "Value": _v("ay", b""),
                    "Flags": _v("as", list(spec.flags)), "MTU": _v("q", getattr(dev.peripheral, "mtu", 247)),
                }
                if "notify" in spec.flags or "indicate" in spec.flags:
                    props["Notifying"] = _v("b", False)
                self._add_object(cpath, {CHARACTERISTIC: props})
                char = _Char(cpath, spec.uuid, spec)
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
                    self._add_object(dpath, {DESCRIPTOR: {
                        "UUID": _v("s", duuid), "Characteristic": _v("o", cpath), "Value": _v("ay", b""),
                        "Flags": _v("as", dflags),
                    }})
                    dev.descs[dpath] = (char, duuid)
                    dev.gatt_paths.append(dpath)

    def _teardown(self, dev: _Device) -> None:
        """The link is gone: remove the GATT objects, then lower ServicesResolved and Connected."""
        dev.connected = False
        for path in reversed(dev.gatt_paths):
            self._remove_object(path)
        dev.gatt_paths.clear()
        dev.chars.clear()
        dev.by_uuid.clear()
        dev.descs.clear()
        self._set(dev.path, DEVICE, ServicesResolved=_v("b", False))
        self._set(dev.path, DEVICE, Connected=_v("b", False))

    def _notify(self, dev: _Device, char_uuid: str, value: bytes) -> None:
        char = dev.by_uuid.get(char_uuid)
        if char is None or not dev.connected:
            return
        props = self._objects[char.path][CHARACTERISTIC]
        props["Value"] = _v("ay", value)
        if char.notifying:
            self._send(Message.new_signal(char.path, PROPERTIES, "PropertiesChanged", "sa{sv}as",
                                          [CHARACTERISTIC, {"Value": props["Value"]}, []]))

    def _link_lost(self, dev: _Device) -> None:
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
        if iface == INTROSPECTABLE and member == "Introspect":
            return Message.new_method_return(msg, "s", [self._introspect(path)])
        if path == "/" and iface == OBJECT_MANAGER and member == "GetManagedObjects":
            return Message.new_method_return(msg, "a{oa{sa{sv}}}", [self._objects])
        if path not in self._objects:
            return Message.new_error(msg, ERR_UNKNOWN_OBJECT, f"no object at {path}")
        if iface == PROPERTIES:
            return self._properties_call(msg)
        handler = self._handlers().get((iface, member))
        if handler is None or iface not in self._objects[path]:
            return Message.new_error(msg, ERR_UNKNOWN_METHOD, f"{iface}.{member} is not a method of {path}")
        try:
            return handler(msg)
        except GattError as e:
            name = ERR_NOT_PERMITTED if e.code == "not_permitted" else ERR_FAILED
            return Message.new_error(msg, name, str(e))

    def _handlers(self) -> dict[tuple[str, str], Callable[[Message], Message | bool]]:
        return {
            (ADAPTER, "StartDiscovery"): self._start_discovery,
            (ADAPTER, "StopDiscovery"): self._stop_discovery,
            (ADAPTER, "SetDiscoveryFilter"): self._set_discovery_filter,
            (ADAPTER, "GetDiscoveryFilters"): lambda m: Message.new_method_return(
                m, "as", [["UUIDs", "RSSI", "Pathloss", "Transport", "DuplicateData", "Discoverable", "Pattern"]]),
            (ADAPTER, "RemoveDevice"): self._remove_device,
            (DEVICE, "Connect"): self._connect,
            (DEVICE, "Disconnect"): self._disconnect,
            (DEVICE, "Pair"): self._pair,
            (CHARACTERISTIC, "ReadValue"): self._read_char,
            (CHARACTERISTIC, "WriteValue"): self._write_char,
            (CHARACTERISTIC, "StartNotify"): self._start_notify,
            (CHARACTERISTIC, "StopNotify"): self._stop_notify,
            (CHARACTERISTIC, "AcquireNotify"): self._not_supported,
            (CHARACTERISTIC, "AcquireWrite"): self._not_supported,
            (DESCRIPTOR, "ReadValue"): self._read_desc,
            (DESCRIPTOR, "WriteValue"): lambda m: Message.new_error(m, ERR_NOT_PERMITTED, "Write not permitted"),
        }

    def _properties_call(self, msg: Message) -> Message:
        path = msg.path or "/"
        if msg.member == "GetAll":
            return Message.new_method_return(msg, "a{sv}", [self._objects[path].get(msg.body[0], {})])
        if msg.member == "Get":
            iface, name = msg.body
            props = self._objects[path].get(iface, {})
            if name not in props:
                return Message.new_error(msg, ERR_INVALID_ARGS, f"no property {iface}.{name} at {path}")
            return Message.new_method_return(msg, "v", [props[name]])
        if msg.member == "Set":
            iface, name, value = msg.body
            writable = {ADAPTER: {"Powered", "Alias", "Discoverable", "Pairable"}, DEVICE: {"Trusted", "Alias", "Blocked"}}
            if name not in writable.get(iface, set()) or iface not in self._objects[path]:
                return Message.new_error(msg, ERR_INVALID_ARGS, f"property {iface}.{name} cannot be set")
            self._set(path, iface, **{name: value})
            return Message.new_method_return(msg)
        return Message.new_error(msg, ERR_UNKNOWN_METHOD, f"{PROPERTIES}.{msg.member}")

    def _introspect(self, path: str) -> str:
        prefix = path.rstrip("/") + "/"
        children = sorted({p[len(prefix):].split("/")[0] for p in self._objects if p.startswith(prefix) and p != path})
        ifaces = list(self._objects.get(path, {}))
        if path == "/":
            ifaces.append(OBJECT_MANAGER)
        body = "".join(f'<interface name="{i}"/>' for i in ifaces + [PROPERTIES, INTROSPECTABLE])
        body += "".join(f'<node name="{c}"/>' for c in children)
        return f"<node>{body}</node>"

    def _start_discovery(self, msg: Message) -> Message:
        sender = msg.sender or ""
        flt = self._discovery[sender] if sender in self._discovery else self._pending_filters.pop(sender, {})
        self._set_discovering(sender, flt)
        return Message.new_method_return(msg)

    def _stop_discovery(self, msg: Message) -> Message:
        self._set_discovering(msg.sender or "", None)
        return Message.new_method_return(msg)

    def _set_discovery_filter(self, msg: Message) -> Message:
        flt = {k: v.value for k, v in msg.body[0].items()}
        sender = msg.sender or ""
        if sender in self._discovery:
            self._discovery[sender] = flt
        else:
            self._pending_filters[sender] = flt
        return Message.new_method_return(msg)

    def _remove_device(self, msg: Message) -> Message:
        path = msg.body[0]
        dev = self.devices.get(path)
        if dev is None or path not in self._objects:
            return Message.new_error(msg, "org.bluez.Error.DoesNotExist", "Does Not Exist")
        if dev.connected:
            dev.peripheral.disconnect()
            self._teardown(dev)
        self._remove_object(path)
        return Message.new_method_return(msg)

    def _dev(self, msg: Message) -> _Device:
        return self.devices[msg.path or ""]

    def _connect(self, msg: Message) -> Message | bool:
        dev = self._dev(msg)
        if dev.connected:
            return Message.new_method_return(msg)
        if dev.connecting:
            return Message.new_error(msg, ERR_IN_PROGRESS, "In Progress")
        dev.connecting = True
        dev.cancel_connect = False
        self._spawn(self._connect_later(msg, dev))
        return True

    async def _connect_later(self, msg: Message, dev: _Device) -> None:
        try:
            await asyncio.sleep(self.connect_latency_s)
            if dev.cancel_connect:
                self._send(Message.new_error(msg, ERR_FAILED, "Operation was cancelled"))
                return
            try:
                dev.peripheral.connect(_DeviceCentral(self, dev))
            except ConnectionDropped:
                self._set(dev.path, DEVICE, Connected=_v("b", True))
                await asyncio.sleep(0.02)
                self._send(Message.new_method_return(msg))
                await asyncio.sleep(0.03)
                self._set(dev.path, DEVICE, Connected=_v("b", False))
                return
            except PeripheralUnavailable:
                await asyncio.sleep(self.connect_fail_s)
                self._send(Message.new_error(msg, ERR_FAILED, "Software caused connection abort"))
                return
            dev.connected = True
            self._set(dev.path, DEVICE, Connected=_v("b", True))
            # let the Connected signal reach every listener before the reply, as bluetoothd's latency does
            await asyncio.sleep(0.02)
            self._send(Message.new_method_return(msg))
            await asyncio.sleep(0.005)
            if dev.connected:
                self._export_gatt(dev)
                self._set(dev.path, DEVICE, ServicesResolved=_v("b", True))
        finally:
            dev.connecting = False

    def _disconnect(self, msg: Message) -> Message:
        dev = self._dev(msg)
        if dev.connecting:
            dev.cancel_connect = True
        if dev.connected:
            dev.peripheral.disconnect()
            self._teardown(dev)
        return Message.new_method_return(msg)

    def _pair(self, msg: Message) -> Message:
        self._set(msg.path or "", DEVICE, Paired=_v("b", True), Bonded=_v("b", True))
        return Message.new_method_return(msg)

    def _char(self, msg: Message) -> tuple[_Device, _Char]:
        path = msg.path or ""
        dev = self.devices[path[: path.rfind("/service")]]
        return dev, dev.chars[path]

    def _read_char(self, msg: Message) -> Message:
        dev, char = self._char(msg)
        if "read" not in char.spec.flags:
            return Message.new_error(msg, ERR_NOT_PERMITTED, "Read not permitted")
        value = bytes(dev.peripheral.read(char.uuid))
        if self._objects[char.path][CHARACTERISTIC]["Value"].value != value:
            self._set(char.path, CHARACTERISTIC, Value=_v("ay", value))
        return Message.new_method_return(msg, "ay", [value])

    def _write_char(self, msg: Message) -> Message:
        dev, char = self._char(msg)
        if not {"write", "write-without-response"} & set(char.spec.flags):
            return Message.new_error(msg, ERR_NOT_PERMITTED, "Write not permitted")
        dev.peripheral.write(char.uuid, bytes(msg.body[0]))
        return Message.new_method_return(msg)

    def _start_notify(self, msg: Message) -> Message:
        dev, char = self._char(msg)
        if not {"notify", "indicate"} & set(char.spec.flags):
            return Message.new_error(msg, ERR_NOT_SUPPORTED, "Operation is not supported")
        if not char.notifying:
            char.notifying = True
            dev.peripheral.set_notify(char.uuid, True)
            self._set(char.path, CHARACTERISTIC, Notifying=_v("b", True))
        return Message.new_method_return(msg)

    def _stop_notify(self, msg: Message) -> Message:
        dev, char = self._char(msg)
        if not char.notifying:
            return Message.new_error(msg, ERR_FAILED, "No notify session started")
        char.notifying = False
        dev.peripheral.set_notify(char.uuid, False)
        self._set(char.path, CHARACTERISTIC, Notifying=_v("b", False))
        return Message.new_method_return(msg)

    def _read_desc(self, msg: Message) -> Message:
        path = msg.path or ""
        dev = self.devices[path[: path.rfind("/service")]]
        char, duuid = dev.descs[path]
        if duuid == CCCD_DESCRIPTOR:
            value = b"\x01\x00" if char.notifying else b"\x00\x00"
        else:
            value = (char.spec.description or "").encode()
        return Message.new_method_return(msg, "ay", [value])

    @staticmethod
    def _not_supported(msg: Message) -> Message:
        return Message.new_error(msg, ERR_NOT_SUPPORTED, "Operation is not supported")


T = TypeVar("T")


class BlueZThread:
    """The simulated BlueZ with its peripherals on an event loop of its own, in a background thread.

    For tests and benchmarks that run the bleak client in the main thread: ``call(fn, *args)`` runs
    ``fn`` in the device thread (use it for every access to a peripheral) and returns its result.
    """

    def __init__(self, bus_address: str, peripherals: Iterable[GattPeripheral], **options: Any) -> None:
        self.bus_address = bus_address
        self.peripherals = list(peripherals)
        self.options = options
        self.bluez: SimulatedBlueZ | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._stopped: asyncio.Event | None = None

    def start(self) -> BlueZThread:
        self._thread = threading.Thread(target=self._main, name="simulated-bluez", daemon=True)
        self._thread.start()
        self._ready.wait(15)
        if self._error is not None:
            raise self._error
        if not self._ready.is_set():
            raise BusUnavailable("the simulated BlueZ did not start within 15 s")
        return self

    def _main(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._serve())
        except BaseException as e:  # reported to start()
            self._error = e
            self._ready.set()
        finally:
            loop.close()

    async def _serve(self) -> None:
        self._stopped = asyncio.Event()
        self.bluez = SimulatedBlueZ(self.peripherals, **self.options)
        await self.bluez.start(self.bus_address)
        self._ready.set()
        await self._stopped.wait()
        for p in self.peripherals:
            close = getattr(p, "aclose", None)
            if close is not None:
                await close()
        await self.bluez.stop()

    def call(self, fn: Callable[..., T], *args: Any) -> T:
        """Run ``fn(*args)`` on the device loop and return its result."""
        assert self._loop is not None

        async def run() -> T:
            return fn(*args)

        return asyncio.run_coroutine_threadsafe(run(), self._loop).result(10)

    def stop(self) -> None:
        if self._loop is not None and self._stopped is not None and self._thread and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stopped.set)
            self._thread.join(10)

    def __enter__(self) -> BlueZThread:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
