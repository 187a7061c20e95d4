"""The wearable link: scan, connect, configure and stream a gyrocal wearable (docs/protocol.md).

``BleLink`` talks Bluetooth LE through bleak; ``InProcessLink`` drives a peripheral object in this
process. Both implement ``WearableLink`` and yield ``SampleBatch`` and ``LinkEvent`` items.
"""

from .base import (
    CommandError,
    ConnectError,
    DeviceInfo,
    DeviceNotFoundError,
    DiscoveredDevice,
    LinkError,
    LinkEvent,
    LinkStats,
    PowerUpReading,
    ReconnectPolicy,
    RecordingBuilder,
    SampleBatch,
    WearableLink,
    WriteBackError,
)
from .decoder import StreamDecoder
from .inprocess import InProcessLink

__all__ = [
    "BleLink", "CommandError", "ConnectError", "DeviceInfo", "PowerUpReading", "DeviceNotFoundError", "DiscoveredDevice",
    "InProcessLink", "LinkError", "LinkEvent", "LinkStats", "ReconnectPolicy", "RecordingBuilder", "SampleBatch",
    "StreamDecoder", "WearableLink", "WriteBackError",
]


def __getattr__(name: str) -> object:
    if name == "BleLink":  # imported on first use: bleak is an optional dependency
        from .ble import BleLink

        return BleLink
    raise AttributeError(name)
