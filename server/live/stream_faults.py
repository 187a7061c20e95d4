"""A wearable's stream that its firmware spoils: so many packets refused as malformed that no calibration can be made
from it. Judged from the link's counts since the session's stream started (server.link: LinkStats)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from .firmware_guidance import malformed_stream

# a wearable whose packets the link refuses this often (at least MALFORMED_MIN of them, MALFORMED_SHARE of all it sent)
# cannot be calibrated: its firmware is at fault, and the session says so at once
MALFORMED_MIN = 20
MALFORMED_SHARE = 0.1


def refused_by_reason(stats: Any) -> dict[str, int]:
    """The packets a link has refused so far, by reason ({} for a link that keeps no counts)."""
    return {} if stats is None else dict(stats.malformed_reasons)


@dataclass
class MalformedWatch:
    """The link's refused and readable packets since the stream started, and whether they are too many."""

    refused_at_start: dict[str, int] = field(default_factory=dict)
    packets_at_start: int = 0
    malformed_at_start: int = 0

    def start(self, stats: Any) -> None:
        """The stream starts: a link kept from an earlier session brings its own counts."""
        self.refused_at_start = refused_by_reason(stats)
        self.packets_at_start = 0 if stats is None else int(stats.packets)
        self.malformed_at_start = 0 if stats is None else int(stats.malformed_packets)

    def verdict(self, stats: Any, firmware: str | None) -> str | None:
        """Why the stream cannot be calibrated, in the clinician's words, when too many packets were refused; else None."""
        if stats is None or stats.malformed_packets - self.malformed_at_start < MALFORMED_MIN:  # asked at every batch
            return None
        before = self.refused_at_start
        refused = {r: c - before.get(r, 0) for r, c in refused_by_reason(stats).items() if c > before.get(r, 0)}
        n = sum(refused.values())
        readable = int(stats.packets) - self.packets_at_start
        if n < MALFORMED_MIN or n < MALFORMED_SHARE * (n + readable):
            return None
        return malformed_stream(refused, readable, firmware)
