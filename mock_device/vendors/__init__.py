"""Simulated commercial wearables: the gyrocal wearable's sessions, clock, faults and clinician behind each
vendor's GATT protocol (``wearable_protocol.vendors``)."""

from __future__ import annotations

from ..wearable import Wearable
from .metawear import MetaWearWearable
from .movella_dot import MovellaDotWearable
from .polar import PolarWearable
from .thingy52 import Thingy52Wearable

WEARABLES: dict[str, type[Wearable]] = {
    w.model.key: w for w in (Wearable, PolarWearable, MetaWearWearable, Thingy52Wearable, MovellaDotWearable)}

__all__ = ["WEARABLES", "MetaWearWearable", "MovellaDotWearable", "PolarWearable", "Thingy52Wearable"]
