"""How far this computer's clock is from the store's database, and what an operator is told when it is too far.

Leases and heartbeats are judged on the database's clock (server.store.fleet), so a gateway whose own clock is off
keeps its wearables. The times it writes into the history (a session's start and end, an accept, the audit log) still
come from its own clock, so an offset beyond MAX_CLOCK_OFFSET_S is said at start, in the log and on /health.
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .store import Store

log = logging.getLogger(__name__)

MAX_CLOCK_OFFSET_S = 2.0  # further from the database's clock than this, the history's times are visibly off


@dataclass(frozen=True)
class ClockReading:
    """One measurement: the database's clock minus this computer's (s), and when it was taken."""

    offset_s: float
    measured_at: datetime

    @property
    def ok(self) -> bool:
        return abs(self.offset_s) <= MAX_CLOCK_OFFSET_S

    def warning(self, store_name: str) -> str | None:
        """The operator's words when the clocks disagree beyond the tolerance; None when they agree."""
        if self.ok:
            return None
        side = "behind" if self.offset_s > 0 else "ahead of"
        return (f"this computer's clock is {abs(self.offset_s):.1f} s {side} the store's ({store_name}): the times this "
                "service writes into the history (sessions, calibrations, the audit log) are off by as much. Leases "
                "and heartbeats use the database's clock and are not affected. Set this computer's clock "
                "(NTP: timedatectl set-ntp true)")


class ClockWatch:
    """The latest reading of the clock offset, measured at start and at every gateway heartbeat."""

    def __init__(self) -> None:
        self.reading: ClockReading | None = None

    async def measure(self, store: Store) -> ClockReading:
        """Measure the offset now; log when it goes beyond the tolerance or comes back within it."""
        offset = await asyncio.to_thread(store.clock_offset_s)
        reading = ClockReading(offset, datetime.now(UTC))
        was_ok = self.reading is None or self.reading.ok
        self.reading = reading
        warning = reading.warning(store.dialect)
        if warning and was_ok:
            log.warning("%s", warning)
        elif warning is None and not was_ok:
            log.info("this computer's clock is within %.0f s of the store's again (%+.2f s)", MAX_CLOCK_OFFSET_S, offset)
        return reading

    def to_dict(self, store_name: str) -> dict[str, object]:
        r = self.reading
        return {"offset_s": None if r is None else round(r.offset_s, 3), "ok": True if r is None else r.ok,
                "measured_at": None if r is None else r.measured_at.isoformat(),
                "warning": None if r is None else r.warning(store_name)}
