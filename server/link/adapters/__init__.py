"""Protocol adapters: one per wearable model (``wearable_protocol.models``), chosen by model name or by
the characteristics the connected device offers."""

from __future__ import annotations

from .base import Adapter, GattIO, StreamSink
from .gyrocal import GyrocalAdapter
from .metawear import MetaWearAdapter
from .movella_dot import MovellaDotAdapter
from .polar import PolarAdapter
from .thingy52 import Thingy52Adapter

ADAPTERS: dict[str, type[Adapter]] = {
    a.model.key: a for a in (GyrocalAdapter, PolarAdapter, MetaWearAdapter, Thingy52Adapter, MovellaDotAdapter)}


def recognise(io: GattIO) -> type[Adapter] | None:
    """The adapter for the connected device, from the characteristics it offers."""
    for adapter in ADAPTERS.values():
        if adapter.recognises(io):
            return adapter
    return None


__all__ = ["ADAPTERS", "Adapter", "GattIO", "StreamSink", "recognise"]
