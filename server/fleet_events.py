"""Live events between the gateways of a fleet, over PostgreSQL's LISTEN/NOTIFY on the store's own database.

Three channels:

- ``gyrocal_fleet``: something the fleet view shows has changed (a lease taken or given back, a calibration
  accepted, a gateway started, what a gateway sees). Every fleet page on every gateway refreshes at once.
- ``gyrocal_follow``: a gateway has a page following a session that another gateway runs. It says so again every
  ``WANT_S`` while the page follows.
- ``gyrocal_session``: the running gateway's snapshots of a session somebody follows, at most one per session every
  ``FLUSH_S``. Each snapshot is the session's whole state, so the latest one is all a follower needs.

A notification carries at most 8000 bytes: a larger snapshot (one with a result) travels zlib-compressed, and one
still too large is read from the store by the follower. The follower also reads the stored session every
``WANT_S``, so a session whose gateway died (ended by the lease sweep) or an event lost while the database restarted
still reaches its page. On SQLite (one service, no fleet) the fleet channel is delivered within the process only.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import logging
import time
import uuid
import zlib
from collections.abc import AsyncIterator, Callable, Coroutine
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError
from sqlalchemy.engine import make_url

from .live.codes import END_STATES
from .live.events import Broadcaster, Event
from .live.snapshot_schema import RemoteGateway, SessionOut

if TYPE_CHECKING:  # loaded where the events run: only a PostgreSQL store has them, an SQLite service never pays for it
    import psycopg

log = logging.getLogger(__name__)

FLEET, FOLLOW, SESSION = "gyrocal_fleet", "gyrocal_follow", "gyrocal_session"
PAYLOAD_MAX = 7900  # PostgreSQL refuses a NOTIFY payload of 8000 bytes or more
FLUSH_S = 0.25  # a followed session's snapshots are relayed at most this often
WANT_S = 10.0  # a follower asks again this often; the running gateway relays for 3 times as long
IDLE_S = 60.0  # a followed session nobody watches (or that ended) is dropped after this long
PING_S = 30.0  # the listening connection is checked this often when nothing arrives
DEBOUNCE_S = 0.2  # a fleet page refreshes at most this often

SessionReader = Callable[[str], SessionOut | None]  # the stored snapshot of a session, or None


def conninfo(db_url: str) -> str | None:
    """The libpq connection string of a PostgreSQL store URL; None for SQLite."""
    url = make_url(db_url)
    if url.get_backend_name() != "postgresql":
        return None
    return url.set(drivername="postgresql").render_as_string(hide_password=False)


@dataclass
class _Followed:
    """A session another gateway runs, followed by pages of this one."""

    broadcaster: Broadcaster
    remote: RemoteGateway  # where it runs
    last_client: float = field(default_factory=time.monotonic)
    ended: float | None = None


class FleetEvents:
    """This service's end of the fleet's channels: it relays the sessions others follow, follows theirs, and tells
    fleet pages (here and on every gateway) when the fleet changed."""

    def __init__(self, db_url: str, stored_snapshot: SessionReader,
                 on_decided: Callable[[str, SessionOut], None]) -> None:
        self.origin = uuid.uuid4().hex[:12]  # tells this process's notifications from others'
        self._conninfo = conninfo(db_url)
        self._stored = stored_snapshot
        self._on_decided = on_decided  # a session running here was accepted or discarded on another gateway
        self.connected = False
        self._latest: dict[str, Event] = {}  # the last snapshot of each session running here
        self._wanted: dict[str, float] = {}  # sessions running here that others follow -> until (monotonic)
        self._followed: dict[str, _Followed] = {}
        self._watchers: set[asyncio.Queue[str]] = set()
        self._out_sessions: dict[str, Event] = {}
        self._out_other: dict[tuple[str, str], None] = {}  # (channel, payload) queued, in order, each once
        self._wake = asyncio.Event()
        self._tasks: list[asyncio.Task[None]] = []
        self._reads: set[asyncio.Task[None]] = set()  # store reads under way (kept referenced until done)

    @property
    def shared(self) -> bool:
        """Whether events reach other gateways (PostgreSQL) or stay in this process (SQLite)."""
        return self._conninfo is not None

    async def start(self) -> None:
        if self._conninfo is None:
            return
        loop = asyncio.get_running_loop()
        self._tasks = [loop.create_task(self._listen(), name="fleet-listen"),
                       loop.create_task(self._send(), name="fleet-send"),
                       loop.create_task(self._follow_loop(), name="fleet-follow")]

    async def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        for followed in self._followed.values():
            followed.broadcaster.close()
        for q in list(self._watchers):
            while q.full():  # the stop must get in: what it displaces no longer matters
                q.get_nowait()
            q.put_nowait("stop")

    # -- the fleet channel ----------------------------------------------------------------------------
    def fleet_changed(self, what: str, device_id: str | None = None) -> None:
        """Tell every fleet page (here at once, elsewhere through the database) that ``what`` changed."""
        self._to_watchers(what)
        if self._conninfo is not None:
            self._queue(FLEET, json.dumps({"o": self.origin, "what": what, "device": device_id}))

    async def fleet_changes(self, quiet_s: float, debounce_s: float = DEBOUNCE_S) -> AsyncIterator[str]:
        """What changed in the fleet, as it happens: a change at once, then at most one every ``debounce_s`` (a burst
        of changes, many sessions starting, comes as one: the last). "quiet" after ``quiet_s`` without a change (time
        passing shows in the fleet too: a gateway falling silent). Ends at shutdown."""
        q: asyncio.Queue[str] = asyncio.Queue(maxsize=1000)
        self._watchers.add(q)
        last = -debounce_s
        try:
            while True:
                try:
                    what = await asyncio.wait_for(q.get(), timeout=quiet_s)
                except TimeoutError:
                    what = "quiet"
                else:
                    await asyncio.sleep(max(0.0, last + debounce_s - time.monotonic()))
                    while not q.empty():
                        what = q.get_nowait()
                if what == "stop":
                    return
                last = time.monotonic()
                yield what
        finally:
            self._watchers.discard(q)

    def _to_watchers(self, what: str) -> None:
        for q in list(self._watchers):
            with contextlib.suppress(asyncio.QueueFull):  # a full queue refreshes anyway
                q.put_nowait(what)

    # -- sessions running here ------------------------------------------------------------------------
    def relay(self, session_id: str, event: Event) -> None:
        """A snapshot of a session running here: sent on to the gateways following it (if any)."""
        self._latest[session_id] = event
        if self._wanted.get(session_id, 0.0) > time.monotonic():
            self._out_sessions[session_id] = event
            self._wake.set()

    def decided(self, session_id: str) -> None:
        """A session was accepted or discarded here: its pages here and on every gateway (and the gateway running it,
        if not this one) learn it from the store."""
        if session_id in self._followed:
            self._spawn(self._refresh(session_id, decided=True))
        if self._conninfo is not None:
            self._queue(SESSION, json.dumps({"o": self.origin, "s": session_id, "decided": True}))

    def session_over(self, session_id: str) -> None:
        """The session running here has closed its stream: nothing more to relay."""
        self._latest.pop(session_id, None)
        self._wanted.pop(session_id, None)

    # -- sessions running elsewhere -------------------------------------------------------------------
    def follow(self, session_id: str, snapshot: SessionOut, remote: RemoteGateway) -> Broadcaster:
        """The stream of a session another gateway runs, starting from its stored ``snapshot``."""
        followed = self._followed.get(session_id)
        if followed is None or followed.broadcaster.closed:
            followed = _Followed(Broadcaster(), remote)
            self._followed[session_id] = followed
            self._publish_followed(session_id, followed, "state", snapshot)
            self._want(session_id)
        followed.last_client = time.monotonic()
        return followed.broadcaster

    def followed(self, session_id: str) -> SessionOut | None:
        """The latest snapshot of a session followed here (None: not followed)."""
        followed = self._followed.get(session_id)
        latest = None if followed is None else followed.broadcaster.latest
        return None if latest is None else SessionOut.model_validate_json(latest.data)

    def _want(self, session_id: str) -> None:
        self._queue(FOLLOW, json.dumps({"o": self.origin, "s": session_id}))

    def _publish_followed(self, session_id: str, followed: _Followed, name: str, snapshot: SessionOut) -> None:
        if followed.broadcaster.closed:
            return
        if followed.ended is not None and snapshot.state not in END_STATES:
            return  # a late relayed snapshot after the stored end state
        followed.broadcaster.publish(name, snapshot.model_copy(update={"remote": followed.remote}))
        if snapshot.state in END_STATES and followed.ended is None:
            followed.ended = time.monotonic()
        if snapshot.decision:
            followed.broadcaster.close()

    def _spawn(self, read: Coroutine[Any, Any, None]) -> None:
        task = asyncio.get_running_loop().create_task(read)
        self._reads.add(task)
        task.add_done_callback(self._reads.discard)

    # -- the database end -----------------------------------------------------------------------------
    def _queue(self, channel: str, payload: str) -> None:
        self._out_other[(channel, payload)] = None
        self._wake.set()

    def _dispatch(self, channel: str, payload: str) -> None:
        try:
            msg = json.loads(payload)
        except ValueError:
            return
        if msg.get("o") == self.origin:
            return
        if channel == FLEET:
            self._to_watchers(str(msg.get("what") or "fleet"))
        elif channel == FOLLOW:
            sid = str(msg.get("s"))
            if sid in self._latest:
                self._wanted[sid] = time.monotonic() + 3 * WANT_S
                self._out_sessions[sid] = self._latest[sid]  # the follower gets the current state at once
                self._wake.set()
        elif channel == SESSION:
            self._on_relayed(msg)

    def _on_relayed(self, msg: dict[str, Any]) -> None:
        sid = str(msg.get("s"))
        if msg.get("decided"):
            if sid in self._latest or sid in self._followed:
                self._spawn(self._refresh(sid, decided=True))
            return
        followed = self._followed.get(sid)
        if followed is None:
            return
        snapshot = relayed_snapshot(msg)
        if snapshot is None:  # too large to travel: the follower reads it from the store
            self._spawn(self._refresh(sid))
            return
        self._publish_followed(sid, followed, str(msg.get("n") or "state"), snapshot)

    async def _refresh(self, session_id: str, decided: bool = False) -> None:
        """Read a session from the store: a followed one that ended (or was decided) shows it; one running here that
        was decided elsewhere is told."""
        try:
            snapshot = await asyncio.to_thread(self._stored, session_id)
        except Exception as exc:  # the store away: the next round tries again
            log.debug("reading session %s failed: %s", session_id, exc)
            return
        if snapshot is None:
            return
        if decided and snapshot.decision and session_id in self._latest:
            self._on_decided(session_id, snapshot)
        followed = self._followed.get(session_id)
        if followed is not None and snapshot.state in END_STATES and (followed.ended is None or decided):
            self._publish_followed(session_id, followed, "decision" if decided else "state", snapshot)

    async def _follow_loop(self) -> None:
        """Ask again for the sessions followed here, read their stored state, and drop the ones nobody watches."""
        while True:
            await asyncio.sleep(WANT_S)
            now = time.monotonic()
            for sid, followed in list(self._followed.items()):
                if followed.broadcaster.clients:
                    followed.last_client = now
                if followed.broadcaster.closed or now - followed.last_client > IDLE_S or (
                        followed.ended is not None and now - followed.ended > IDLE_S):
                    followed.broadcaster.close()
                    del self._followed[sid]
                    continue
                self._want(sid)
                await self._refresh(sid)

    async def _send(self) -> None:
        """Send what is queued, in one transaction every ``FLUSH_S`` at most; reconnect when the database went away
        (what was queued meanwhile is sent then: sessions' latest snapshots, fleet changes once each)."""
        import psycopg

        conn: psycopg.AsyncConnection[Any] | None = None
        while True:
            await self._wake.wait()
            self._wake.clear()
            batch = [(SESSION, session_payload(self.origin, sid, ev)) for sid, ev in self._out_sessions.items()]
            batch += list(self._out_other)
            self._out_sessions.clear()
            self._out_other.clear()
            try:
                if conn is None or conn.closed:
                    conn = await psycopg.AsyncConnection.connect(self._conninfo or "", autocommit=True, connect_timeout=5)
                async with conn.transaction():
                    async with conn.cursor() as cur:
                        await cur.executemany("SELECT pg_notify(%s, %s)", batch)
            except (psycopg.Error, OSError) as exc:
                log.warning("fleet events could not be sent (%s); trying again", exc)
                if conn is not None:
                    await conn.close()
                conn = None
                for channel, payload in batch:
                    if channel != SESSION:
                        self._out_other.setdefault((channel, payload), None)
                self._wake.set()
                await asyncio.sleep(1.0)
                continue
            await asyncio.sleep(FLUSH_S)

    async def _listen(self) -> None:
        import psycopg

        delay = 0.5
        while True:
            try:
                conn = await psycopg.AsyncConnection.connect(self._conninfo or "", autocommit=True, connect_timeout=5)
                async with conn:
                    for channel in (FLEET, FOLLOW, SESSION):
                        await conn.execute(f"LISTEN {channel}")
                    if not self.connected:
                        log.info("following the fleet's events on the store's database")
                    self.connected, delay = True, 0.5
                    self._resync()
                    while True:
                        async for note in conn.notifies(timeout=PING_S):
                            try:
                                self._dispatch(note.channel, note.payload)
                            except Exception:  # one malformed notification must not stop the others
                                log.exception("a fleet notification on %s could not be read", note.channel)
                        await conn.execute("SELECT 1")  # a link that died quietly shows here
            except (psycopg.Error, OSError) as exc:
                if self.connected:
                    log.warning("lost the fleet's events (%s); reconnecting", exc)
                self.connected = False
            await asyncio.sleep(delay)
            delay = min(2 * delay, 5.0)

    def _resync(self) -> None:
        """After (re)connecting: anything may have changed meanwhile; ask again for what is followed here."""
        self._to_watchers("reconnected")
        for sid in list(self._followed):
            self._want(sid)
            self._spawn(self._refresh(sid))


def session_payload(origin: str, session_id: str, event: Event) -> str:
    """A session's snapshot as one notification's payload: as it is, zlib-compressed when that is too large, or only
    its session id (the receiver reads the store) when even that is."""
    msg: dict[str, Any] = {"o": origin, "s": session_id, "n": event.name, "d": event.data}
    payload = json.dumps(msg, separators=(",", ":"))
    if len(payload.encode()) <= PAYLOAD_MAX:
        return payload
    del msg["d"]
    msg["z"] = base64.b64encode(zlib.compress(event.data.encode(), 6)).decode()
    payload = json.dumps(msg, separators=(",", ":"))
    if len(payload.encode()) <= PAYLOAD_MAX:
        return payload
    del msg["z"]
    return json.dumps(msg, separators=(",", ":"))


def relayed_snapshot(msg: dict[str, Any]) -> SessionOut | None:
    """The snapshot a session notification carries (None: it was too large to travel, or is not one this gateway
    reads, e.g. from another version: the follower then reads the store)."""
    try:
        if "d" in msg:
            return SessionOut.model_validate_json(msg["d"])
        if "z" in msg:
            return SessionOut.model_validate_json(zlib.decompress(base64.b64decode(msg["z"])))
    except (ValidationError, ValueError, zlib.error):
        log.warning("a relayed snapshot of session %s could not be read; reading the store instead", msg.get("s"))
    return None
