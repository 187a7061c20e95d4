"""Server-Sent Events for a session: numbered snapshots, a replay buffer, one queue per client.

Each event is a full snapshot of the session with an increasing id, so a client that reconnects with
Last-Event-ID gets what it missed (or, if that fell out of the buffer, the latest snapshot, which is
all it needs).
"""

from __future__ import annotations

import asyncio
import json
from collections import deque
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from .snapshot_schema import SessionOut

KEEPALIVE_S = 15.0
RETRY_MS = 1000
CLOSED_RETRY_MS = 3_600_000


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


def dumps(obj: Any) -> str:
    return json.dumps(obj, separators=(",", ":"), default=_json_default, allow_nan=False)


@dataclass(frozen=True)
class Event:
    id: int
    name: str
    data: str  # JSON

    def encode(self) -> bytes:
        return f"id: {self.id}\nevent: {self.name}\ndata: {self.data}\n\n".encode()


_CLOSE = object()


class Broadcaster:
    """Fans a session's snapshots out to its SSE clients; keeps the last `history` for replay."""

    def __init__(self, history: int = 2000, queue_size: int = 2000) -> None:
        self._history: deque[Event] = deque(maxlen=history)
        self._queues: set[asyncio.Queue[Any]] = set()
        self._queue_size = queue_size
        self._next_id = 1
        self.closed = False

    @property
    def latest(self) -> Event | None:
        return self._history[-1] if self._history else None

    @property
    def clients(self) -> int:
        return len(self._queues)

    def publish(self, name: str, snapshot: SessionOut) -> Event:
        """Number a snapshot, keep it, and queue it for every client (call from the event loop)."""
        numbered = snapshot.model_copy(update={"event_id": self._next_id})
        # pydantic's own serialiser (NaN and infinity as null), three times as fast as a dict through json.dumps
        ev = Event(self._next_id, name, numbered.model_dump_json(exclude_unset=True))
        self._next_id += 1
        self._history.append(ev)
        for q in list(self._queues):
            try:
                q.put_nowait(ev)
            except asyncio.QueueFull:
                # a client that cannot keep up is dropped; it reconnects with Last-Event-ID
                self._queues.discard(q)
                _force_close(q)
        return ev

    def close(self) -> None:
        """End every client's stream (service shutdown)."""
        self.closed = True
        for q in list(self._queues):
            _force_close(q)
        self._queues.clear()

    def replay(self, last_id: int | None) -> list[Event]:
        """What a (re)connecting client gets first."""
        if not self._history:
            return []
        if last_id is None or last_id < self._history[0].id - 1 or last_id >= self._next_id:
            return [self._history[-1]]
        return [ev for ev in self._history if ev.id > last_id]

    async def stream(self, last_id: int | None = None, keepalive_s: float = KEEPALIVE_S) -> AsyncIterator[bytes]:
        """The SSE byte stream of one client."""
        q: asyncio.Queue[Any] = asyncio.Queue(maxsize=self._queue_size)
        if not self.closed:
            self._queues.add(q)
        try:
            # a finished stream tells EventSource to wait long before trying again
            yield f"retry: {CLOSED_RETRY_MS if self.closed else RETRY_MS}\n\n".encode()
            sent = last_id or 0
            for ev in self.replay(last_id):
                sent = ev.id
                yield ev.encode()
            if self.closed:
                return
            while True:
                try:
                    item = await asyncio.wait_for(q.get(), timeout=keepalive_s)
                except TimeoutError:
                    yield b": keepalive\n\n"
                    continue
                if item is _CLOSE:
                    return
                if item.id <= sent:
                    continue
                sent = item.id
                yield item.encode()
        finally:
            self._queues.discard(q)


def _force_close(q: asyncio.Queue[Any]) -> None:
    while True:
        try:
            q.put_nowait(_CLOSE)
            return
        except asyncio.QueueFull:
            try:
                q.get_nowait()
            except asyncio.QueueEmpty:
                pass

