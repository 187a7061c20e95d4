"""Outlier packets: one corrupt value (a time stamp, a sequence number) is dropped, never trusted as the new clock.

A decoder judges each packet's own claim (its sequence number, its time stamp) against an independent witness (the
device's clock, the packet's arrival). A packet that disagrees is a suspect: counted and dropped. Only when
RESYNC_AFTER suspects in a row agree with each other has the device really jumped (a clock reset, a counter
restarted without saying so), and the decoder follows them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Generic, TypeVar

RESYNC_AFTER = 3  # consecutive outliers that agree with each other: the stream really jumped; follow it
LONG_GAP_S = 10.0  # a packet this far ahead of the last waits for the next ones to confirm it (16-bit sequence
# numbers wrap every few minutes, so a corrupt time stamp can look like a long outage)
# two gaps agree (in samples) within half a sample (so that no two packets' samples can overlap) plus this share of
# the gap (the rate estimate's error, before it is fitted, over a long gap)
TOLERANCE_SAMPLES = 0.5
TOLERANCE_FRACTION = 0.05

T = TypeVar("T")


class Suspects(Generic[T]):
    """The outlier packets in a row; ``add`` says when they are enough, and consistent enough, to follow."""

    def __init__(self, resync_after: int = RESYNC_AFTER) -> None:
        self.resync_after = resync_after
        self.items: list[T] = []

    def clear(self) -> None:
        self.items = []

    def add(self, item: T, follows: Callable[[T, T], bool]) -> bool:
        """Another outlier; ``follows(previous, item)`` whether it continues the previous one. True when the
        last RESYNC_AFTER outliers form one consistent stream (then follow it and clear)."""
        if self.items and not follows(self.items[-1], item):
            self.items = []
        self.items.append(item)
        return len(self.items) >= self.resync_after
