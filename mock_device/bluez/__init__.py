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
``bluetoothctl --version`` once per process; :func:`write_bluetoothctl_shim` provides one."""

from .bus import BusUnavailable, PrivateBus, write_bluetoothctl_shim
from .names import (
    ADAPTER,
    ADAPTER_PATH,
    BATTERY,
    BLUEZ,
    BLUEZ_VERSION,
    CHARACTERISTIC,
    DESCRIPTOR,
    DEVICE,
    ERR_FAILED,
    ERR_IN_PROGRESS,
    ERR_INVALID_ARGS,
    ERR_NOT_CONNECTED,
    ERR_NOT_PERMITTED,
    ERR_NOT_SUPPORTED,
    ERR_UNKNOWN_METHOD,
    ERR_UNKNOWN_OBJECT,
    INTROSPECTABLE,
    OBJECT_MANAGER,
    PROPERTIES,
    SERVICE,
)
from .service import SimulatedBlueZ, log
from .thread import BlueZThread, T
