"""A simulated clinician's eyes (mock_device.follower) look for a session only when their wearable starts streaming:
an idle simulated wearable costs the service a look every few seconds, not five a second (a service with thirteen
prompt-following wearables once spent most of a core answering them)."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from mock_device.follower import IDLE_LOOK_S, LOOK_S, POLL_S, SessionFollower


def _send(handler: BaseHTTPRequestHandler, content_type: str, body: bytes) -> None:
    handler.send_response(200)
    handler.send_header("Content-Type", content_type)
    handler.send_header("Content-Length", str(len(body)))  # with a length, an event stream ends after this body
    handler.end_headers()
    handler.wfile.write(body)


@pytest.fixture
def service() -> Iterator[tuple[str, list[float]]]:
    """A stand-in for the service's ``GET /devices/{id}`` (the wearable is in no session): the times it was asked."""
    asked: list[float] = []

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 (the standard library's name)
            asked.append(time.monotonic())
            _send(self, "application/json", json.dumps({"id": "mock-1", "active_session": None}).encode())

        def log_message(self, *args: object) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}", asked
    finally:
        server.shutdown()


def test_an_idle_wearable_is_looked_for_every_few_seconds_and_at_once_when_it_streams(service) -> None:
    base, asked = service
    follower = SessionFollower("mock-1", lambda snap: None, lambda: base).start()
    try:
        time.sleep(2.0)
        assert len(asked) <= 1, asked  # idle: at most one look in IDLE_LOOK_S
        woken = time.monotonic()
        follower.wake()  # its stream started: looked for at once, then every POLL_S for LOOK_S
        time.sleep(LOOK_S + 1.0)
        looks = [t for t in asked if t >= woken]
        assert looks and looks[0] - woken < 0.5, looks
        assert LOOK_S / POLL_S / 2 <= len(looks) <= LOOK_S / POLL_S + 2, len(looks)
        assert looks[-1] - woken <= LOOK_S + POLL_S + 0.5  # then it stops looking
    finally:
        follower.stop()
    assert IDLE_LOOK_S >= 2.0


def test_a_session_stream_that_closes_early_is_opened_again_until_the_session_ends() -> None:
    """The service drops an event reader that fell behind (a busy machine): the eyes open the stream again at once,
    as the page does, instead of going blind for the rest of the session."""
    streams: list[float] = []
    sent = [{"state": "turn_x", "phase": "ready"}, {"state": "turn_y", "phase": "ready"}, {"state": "done"}]

    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def do_GET(self) -> None:  # noqa: N802 (the standard library's name)
            if self.path.startswith("/devices/"):
                active = "s1" if len(streams) < len(sent) else None
                _send(self, "application/json", json.dumps({"id": "mock-1", "active_session": active}).encode())
                return
            streams.append(time.monotonic())  # one snapshot on each stream, then the service closes it
            _send(self, "text/event-stream", f"id: {len(streams)}\ndata: {json.dumps(sent[len(streams) - 1])}\n\n".encode())

        def log_message(self, *args: object) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    seen: list[dict] = []
    follower = SessionFollower("mock-1", seen.append, lambda: f"http://127.0.0.1:{server.server_address[1]}").start()
    try:
        follower.wake()
        deadline = time.monotonic() + 10.0
        while len(seen) < len(sent) and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        follower.stop()
        server.shutdown()
    assert [s["state"] for s in seen] == ["turn_x", "turn_y", "done"], seen
    assert streams[-1] - streams[0] < 2.0, streams  # opened again at once, not at the next idle look
