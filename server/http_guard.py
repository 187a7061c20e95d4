"""The HTTP server's guard against connections that hold a file descriptor without making a request.

uvicorn closes an idle keep-alive connection, but not one that trickles its request headers (a header line every
few seconds: "slowloris"), and it accepts connections until the process runs out of file descriptors, after which
`/health` itself cannot be answered. Two bounds close that:

- a request's headers must be complete within ``header_timeout_s`` of the connection opening (or of the previous
  response ending); a connection still sending them then is closed;
- at most ``max_connections`` connections are open; a new one beyond that evicts the longest-waiting connection
  that has not completed its headers, or, when every open connection is a real request (event streams, uploads),
  is closed at once.

``max_connections`` stays below the process's file limit by RESERVED_FILES, which covers what the service opens
itself and the ACCEPT_BURST connections asyncio accepts before the first of them reaches the bound; the soft limit
is lifted to the hard limit at start (``raise_file_limit``).
"""

from __future__ import annotations

import asyncio
import logging
import resource
import time
from typing import Any

from uvicorn.protocols.http.h11_impl import H11Protocol

log = logging.getLogger(__name__)

ACCEPT_BURST = 128  # connections asyncio accepts in one go before any is seen, and the kernel queues (uvicorn's backlog=)
# descriptors kept for the store, the wearables' links, workers and logs (some 20-60), and for one accept burst twice:
# the connections it brings and those they evict, whose descriptors are freed on the loop's next turn
RESERVED_FILES = 100 + 2 * ACCEPT_BURST


def raise_file_limit() -> int:
    """Lift this process's soft limit on open files to its hard limit; the limit now in force."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard == resource.RLIM_INFINITY or soft < hard:
        target = 1 << 20 if hard == resource.RLIM_INFINITY else hard
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
            soft = target
        except (ValueError, OSError):
            pass
    return soft


def connection_bound(asked: int, file_limit: int) -> int:
    """The connections to allow: as asked, but never so many that the process runs out of file descriptors."""
    return max(16, min(asked, file_limit - RESERVED_FILES))


def guarded_protocol(header_timeout_s: float, max_connections: int) -> type[H11Protocol]:
    """uvicorn's h11 protocol with the header deadline and the connection bound (pass it as ``http=``)."""

    class GuardedH11Protocol(H11Protocol):
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            self.header_deadline: asyncio.TimerHandle | None = None
            self.waiting_since = time.monotonic()

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            if len(self.connections) >= max_connections and not self._evict_one_waiting():
                transport.close()  # every open connection is a request in progress: this one waits for a retry
                return
            super().connection_made(transport)
            self._arm_header_deadline()

        def on_response_complete(self) -> None:
            super().on_response_complete()
            self._arm_header_deadline()  # the next request on this connection has its own deadline

        def connection_lost(self, exc: Exception | None) -> None:
            if self.transport is None:  # closed in connection_made: uvicorn never knew of it
                return
            self._disarm_header_deadline()
            super().connection_lost(exc)

        # -- the header deadline ---------------------------------------------------------------------------
        def waiting_for_headers(self) -> bool:
            return self.cycle is None or self.cycle.response_complete

        def _arm_header_deadline(self) -> None:
            self._disarm_header_deadline()
            self.waiting_since = time.monotonic()
            self.header_deadline = self.loop.call_later(header_timeout_s, self._header_deadline_passed)

        def _disarm_header_deadline(self) -> None:
            if self.header_deadline is not None:
                self.header_deadline.cancel()
                self.header_deadline = None

        def _header_deadline_passed(self) -> None:
            self.header_deadline = None
            if self.waiting_for_headers() and not self.transport.is_closing():
                self.transport.close()

        def _evict_one_waiting(self) -> bool:
            """Close the connection that has waited longest for its request's headers; False if none waits."""
            waiting: list[Any] = [p for p in self.connections
                                  if isinstance(p, GuardedH11Protocol) and p.waiting_for_headers() and not p.transport.is_closing()]
            if not waiting:
                return False
            oldest = min(waiting, key=lambda p: p.waiting_since)
            oldest.transport.close()
            self.connections.discard(oldest)  # closing is asynchronous; the count must drop now
            return True

    return GuardedH11Protocol
