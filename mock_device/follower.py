"""A simulated clinician's eyes: the session events of one wearable, read over HTTP as the page reads them.

``SessionFollower`` runs in a thread of its own. Woken when its wearable starts streaming (``wake``: a session or a
verification has connected to it), it asks the service which session its wearable is in (``GET /devices/{id}``),
follows that session's Server-Sent Events (``GET /sessions/{sid}/events``) and hands every snapshot to a callback,
until the session ends; then it waits for the next stream. While nothing streams it looks only every few seconds, so
idle simulated wearables cost the service nothing. A verification turn
(``GET /verifications/{id}``) is polled instead, and its request for the turn handed on as a prompt to turn. The service's address
comes from a callable because a service learns its port only once it listens. ``KitFollower`` is the eyes of the clinician
who turns a tray of wearables: it follows the events of the kit session that holds one of them, as the kit page does.
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from collections.abc import Callable
from typing import Any

import httpx

END_STATES = {"done", "failed", "cancelled"}
POLL_S = 0.2  # between looks for the session of a wearable that has started streaming, and a verification's polls
LOOK_S = 3.0  # how long a wearable that started streaming is looked for in a session
IDLE_LOOK_S = 5.0  # between looks while no wearable streams (a stream the follower was not woken for is found then)


class SessionFollower:
    """Follows the sessions of ``device_id`` on the service at ``base_url()`` and calls ``on_snapshot`` with each."""

    def __init__(self, device_id: str, on_snapshot: Callable[[dict[str, Any]], None], base_url: Callable[[], str | None]) -> None:
        self.device_id = device_id
        self.on_snapshot = on_snapshot
        self.base_url = base_url
        token = os.environ.get("GYROCAL_API_TOKEN")  # needed only when the service asks a token for reads
        self.headers = {"Authorization": f"Bearer {token}"} if token else {}
        self._stop = threading.Event()
        self._woken = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"follow-{device_id}", daemon=True)
        # one client for the thread's life: its connections are kept open between looks, and it is built once (a client
        # loads the CA bundle as it is built, 20 ms of CPU, once a look while a stream is looked for)
        self._http: httpx.Client | None = None

    def start(self) -> SessionFollower:
        # httpx logs every request at INFO: in the service's log, one line per look for a session, five a second
        logging.getLogger("httpx").setLevel(max(logging.WARNING, logging.getLogger("httpx").level))
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._woken.set()

    def wake(self) -> None:
        """The wearable started streaming: look for its session now (from any thread)."""
        self._woken.set()

    def _run(self) -> None:
        with httpx.Client(headers=self.headers) as self._http:
            self._follow_all()

    def _client(self) -> httpx.Client:
        if self._http is None:
            raise RuntimeError("the follower's client exists only on its own thread, once started")
        return self._http

    def _follow_all(self) -> None:
        done: set[str] = set()
        while not self._stop.is_set():
            woken = self._woken.wait(IDLE_LOOK_S)
            self._woken.clear()
            until = time.monotonic() + (LOOK_S if woken else 0.0)
            while not self._stop.is_set():
                if self._look(done) or time.monotonic() >= until:
                    break
                self._stop.wait(POLL_S)

    def _look(self, done: set[str]) -> bool:
        """Follow the wearable's session to its end if it is in one not followed yet; whether it was."""
        base = self.base_url()
        if not base:
            return False
        try:
            sid = self._active_session(base)
            if sid and sid not in done:
                self._follow(base, sid)
                done.add(sid)
                return True
        except (httpx.HTTPError, ValueError):
            pass  # the service is starting or stopping: look again
        return False

    def _active_session(self, base: str) -> str | None:
        r = self._client().get(f"{base}/devices/{self.device_id}", timeout=5.0)
        return r.json().get("active_session") if r.status_code == 200 else None

    def _follow_verification(self, base: str, vid: str) -> None:
        """A verification turn (``GET /verifications/{id}``, polled as the page does): when it asks for the turn, the
        hand is told what a guided session's ready-for-x prompt tells it."""
        while not self._stop.is_set():
            r = self._client().get(f"{base}/verifications/{vid}", timeout=5.0)
            if r.status_code != 200:
                return
            state = r.json().get("state")
            if state == "turn":
                self.on_snapshot({"state": "turn_x", "phase": "ready", "axis": "x", "attempt": 1, "warnings": []})
            if state in ("done", "failed"):
                return
            self._stop.wait(POLL_S)

    def _follow(self, base: str, sid: str) -> None:
        """Hand each snapshot of the session to the callback until it ends. A stream that closes first (the service
        drops a reader that fell behind; a proxy times out) is opened again at once, as the page's EventSource does,
        while the session is still the one this follower looks for: each event is a whole snapshot, so the next one
        tells the hand everything it missed."""
        deadline = time.monotonic() + 3600.0
        while not self._stop.is_set() and time.monotonic() < deadline:
            try:
                if self._follow_stream(base, sid, deadline):
                    return
            except httpx.HTTPError:
                pass  # the stream broke mid-way: as a close
            if self._active_session(base) != sid:
                return
            self._stop.wait(POLL_S)

    def _follow_stream(self, base: str, sid: str, deadline: float) -> bool:
        """One connection to the session's events; whether the session is over for this follower (it ended, it is a
        verification followed to its end, it is gone, or the follower stops)."""
        with self._client().stream("GET", f"{base}/sessions/{sid}/events", timeout=httpx.Timeout(30.0)) as r:
            if r.status_code == 404:  # not a guided session: a verification turn
                self._follow_verification(base, sid)
                return True
            if r.status_code != 200:
                return r.status_code < 500  # a service too busy to answer is asked again
            for line in r.iter_lines():
                if self._stop.is_set() or time.monotonic() > deadline:
                    return True
                if not line.startswith("data:"):
                    continue
                snap = json.loads(line[5:])
                self.on_snapshot(snap)
                if snap.get("state") in END_STATES:
                    return True
        return False


class KitFollower(SessionFollower):
    """Follows the kit sessions that hold any of ``device_ids`` (the wearables in the tray: ``active_kit`` of ``GET
    /devices/{id}``; a kit may leave some of the tray's out) through their event streams, as the kit page does, and
    calls ``on_snapshot`` with each snapshot until the kit ends."""

    def __init__(self, device_ids: list[str], on_snapshot: Callable[[dict[str, Any]], None],
                 base_url: Callable[[], str | None]) -> None:
        super().__init__(device_ids[0], on_snapshot, base_url)
        self.device_ids = list(device_ids)

    def _active_session(self, base: str) -> str | None:
        for device_id in self.device_ids:
            r = self._client().get(f"{base}/devices/{device_id}", timeout=5.0)
            kit = r.json().get("active_kit") if r.status_code == 200 else None
            if kit:
                return str(kit)
        return None
