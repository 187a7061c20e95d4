"""The org.bluez methods a central calls on the simulated BlueZ: discovery and its filter, removing a device,
connecting and disconnecting, pairing, and reading, writing and subscribing to characteristics."""

from __future__ import annotations

import asyncio
from typing import Any

from dbus_fast import Message

from wearable_protocol import CCCD_DESCRIPTOR, ConnectionDropped, PeripheralUnavailable

from . import names as N
from .objects import Char, Device, DeviceCentral, variant


class BlueZMethods:
    """The method calls of ``SimulatedBlueZ`` (which holds the object tree they act on)."""

    devices: dict[str, Device]
    connect_latency_s: float
    connect_fail_s: float
    _objects: dict[str, Any]
    _discovery: dict[str, Any]
    _pending_filters: dict[str, Any]

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

    def _dev(self, msg: Message) -> Device:
        return self.devices[msg.path or ""]

    def _connect(self, msg: Message) -> Message | bool:
        dev = self._dev(msg)
        if dev.connected:
            return Message.new_method_return(msg)
        if dev.connecting:
            return Message.new_error(msg, N.ERR_IN_PROGRESS, "In Progress")
        dev.connecting = True
        dev.cancel_connect = False
        self._spawn(self._connect_later(msg, dev))
        return True

    async def _connect_later(self, msg: Message, dev: Device) -> None:
        try:
            await asyncio.sleep(self.connect_latency_s)
            if dev.cancel_connect:
                self._send(Message.new_error(msg, N.ERR_FAILED, "Operation was cancelled"))
                return
            try:
                dev.peripheral.connect(DeviceCentral(self, dev))
            except ConnectionDropped:
                self._set(dev.path, N.DEVICE, Connected=variant("b", True))
                await asyncio.sleep(0.02)
                self._send(Message.new_method_return(msg))
                await asyncio.sleep(0.03)
                self._set(dev.path, N.DEVICE, Connected=variant("b", False))
                return
            except PeripheralUnavailable:
                await asyncio.sleep(self.connect_fail_s)
                self._send(Message.new_error(msg, N.ERR_FAILED, "Software caused connection abort"))
                return
            dev.connected = True
            self._set(dev.path, N.DEVICE, Connected=variant("b", True))
            # let the Connected signal reach every listener before the reply, as bluetoothd's latency does
            await asyncio.sleep(0.02)
            self._send(Message.new_method_return(msg))
            await asyncio.sleep(0.005)
            if dev.connected:
                self._export_gatt(dev)
                self._set(dev.path, N.DEVICE, ServicesResolved=variant("b", True))
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
        self._set(msg.path or "", N.DEVICE, Paired=variant("b", True), Bonded=variant("b", True))
        return Message.new_method_return(msg)

    def _char(self, msg: Message) -> tuple[Device, Char]:
        path = msg.path or ""
        dev = self.devices[path[: path.rfind("/service")]]
        return dev, dev.chars[path]

    def _read_char(self, msg: Message) -> Message:
        dev, char = self._char(msg)
        if "read" not in char.spec.flags:
            return Message.new_error(msg, N.ERR_NOT_PERMITTED, "Read not permitted")
        value = bytes(dev.peripheral.read(char.uuid))
        if self._objects[char.path][N.CHARACTERISTIC]["Value"].value != value:
            self._set(char.path, N.CHARACTERISTIC, Value=variant("ay", value))
        return Message.new_method_return(msg, "ay", [value])

    def _write_char(self, msg: Message) -> Message:
        dev, char = self._char(msg)
        if not {"write", "write-without-response"} & set(char.spec.flags):
            return Message.new_error(msg, N.ERR_NOT_PERMITTED, "Write not permitted")
        dev.peripheral.write(char.uuid, bytes(msg.body[0]))
        return Message.new_method_return(msg)

    def _start_notify(self, msg: Message) -> Message:
        dev, char = self._char(msg)
        if not {"notify", "indicate"} & set(char.spec.flags):
            return Message.new_error(msg, N.ERR_NOT_SUPPORTED, "Operation is not supported")
        if not char.notifying:
            char.notifying = True
            dev.peripheral.set_notify(char.uuid, True)
            self._set(char.path, N.CHARACTERISTIC, Notifying=variant("b", True))
        return Message.new_method_return(msg)

    def _stop_notify(self, msg: Message) -> Message:
        dev, char = self._char(msg)
        if not char.notifying:
            return Message.new_error(msg, N.ERR_FAILED, "No notify session started")
        char.notifying = False
        dev.peripheral.set_notify(char.uuid, False)
        self._set(char.path, N.CHARACTERISTIC, Notifying=variant("b", False))
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
        return Message.new_error(msg, N.ERR_NOT_SUPPORTED, "Operation is not supported")
