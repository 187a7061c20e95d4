"""Connections that never finish their request: raw sockets trickling headers against the real service, under the
1,024-file limit systemd gives a service by default, and the log that must not repeat an error a million times."""

from __future__ import annotations

import logging
import resource
import socket
import threading
import time
from pathlib import Path

import httpx
from server_fixtures import RunningService

from server.config import DEFAULT_MAX_CONNECTIONS
from server.http_guard import connection_bound
from server.log_repeats import RepeatFilter

FILE_LIMIT = ["prlimit", "--nofile=1024:1024"]  # soft and hard: the service cannot raise it
HALF_OPEN = 1100


def _trickle(port: int, stop: threading.Event, opened: list[int]) -> None:
    """Keep HALF_OPEN connections open, each sending one more header line every second and never the blank line that
    ends the headers; reopen those the service closes (as an attacker would)."""
    socks: list[socket.socket | None] = [None] * HALF_OPEN
    while not stop.is_set():
        for i in range(HALF_OPEN):
            s = socks[i]
            try:
                if s is None:
                    s = socket.create_connection(("127.0.0.1", port), timeout=2)
                    s.sendall(b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\n")
                    socks[i] = s
                    opened[0] += 1
                else:
                    s.sendall(b"X-Slow: 1\r\n")
            except OSError:
                if s is not None:
                    s.close()
                socks[i] = None
            if stop.is_set():
                break
        stop.wait(1.0)
    for s in socks:
        if s is not None:
            s.close()


def test_half_open_connections_under_a_1024_file_limit_leave_health_answering(tmp_path: Path) -> None:
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, min(hard, 4096)), hard))  # this test's own sockets
    svc = RunningService(["--header-timeout-s", "3"], f"sqlite:///{tmp_path / 'store.sqlite3'}", prefix=FILE_LIMIT).start()
    stop = threading.Event()
    opened = [0]
    attack = threading.Thread(target=_trickle, args=(svc.port, stop, opened), daemon=True)
    try:
        bound = connection_bound(DEFAULT_MAX_CONNECTIONS, 1024)
        assert 400 < bound < 1000 and f"at most {bound} connections, not 1000" in svc.output()  # said at start
        attack.start()
        time.sleep(3.0)
        answers = []
        for _ in range(20):  # a load balancer's probe, on a fresh connection each time
            try:
                answers.append(httpx.get(svc.base + "/health", timeout=5.0, verify=False).status_code)
            except httpx.HTTPError as exc:
                answers.append(type(exc).__name__)
            time.sleep(0.3)
        assert answers == [200] * 20, answers
        assert opened[0] > HALF_OPEN  # connections were closed under the attacker and reopened
    finally:
        stop.set()
        attack.join(30)
        log = svc.output()
        svc.stop()
    assert log.count("Too many open files") <= 10 and len(log) < 200_000, (len(log), log[-2000:])


def test_a_request_whose_headers_never_end_is_closed_and_a_whole_one_is_answered(tmp_path: Path) -> None:
    svc = RunningService(["--header-timeout-s", "3"], f"sqlite:///{tmp_path / 'store.sqlite3'}").start()
    try:
        slow = socket.create_connection(("127.0.0.1", svc.port), timeout=15)
        slow.sendall(b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        closed = False
        deadline = time.monotonic() + 30
        while not closed and time.monotonic() < deadline:  # a header line every 0.3 s: never idle, never finished
            time.sleep(0.3)
            try:
                slow.sendall(b"X-Slow: 1\r\n")
                slow.settimeout(0.01)
                closed = slow.recv(1024) == b""
            except (BrokenPipeError, ConnectionResetError):
                closed = True
            except TimeoutError:
                pass
        assert closed, "the service kept a connection whose headers never ended"
        slow.close()
        with socket.create_connection(("127.0.0.1", svc.port), timeout=15) as ok:  # one keep-alive connection,
            for _ in range(14):  # whole requests 0.3 s apart, 4 s in all, past the 3 s deadline: each has its own
                ok.sendall(b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
                assert _response(ok).startswith(b"HTTP/1.1 200")
                time.sleep(0.3)
    finally:
        svc.stop()


def _response(sock: socket.socket) -> bytes:
    """One whole HTTP response (headers and a Content-Length body) from a keep-alive connection."""
    data = b""
    while b"\r\n\r\n" not in data:
        data += sock.recv(65536)
    head, _, body = data.partition(b"\r\n\r\n")
    length = next(int(line.split(b":")[1]) for line in head.split(b"\r\n") if line.lower().startswith(b"content-length:"))
    while len(body) < length:
        body += sock.recv(65536)
    return head + b"\r\n\r\n" + body


def _record(msg: str = "socket.accept() out of system resource") -> logging.LogRecord:
    try:
        raise OSError(24, "Too many open files")
    except OSError:
        import sys

        return logging.LogRecord("asyncio", logging.ERROR, __file__, 1, msg, None, sys.exc_info())


def test_a_repeated_error_is_logged_a_few_times_then_counted() -> None:
    now = [0.0]
    rf = RepeatFilter(burst=5, window_s=60.0, clock=lambda: now[0])
    passed = [r for r in (_record() for _ in range(100_000)) if rf.filter(r)]
    assert len(passed) == 5 and "further copies are dropped and counted" in str(passed[-1].msg)
    assert rf.filter(_record("another message"))  # a different message has its own count
    now[0] = 61.0
    nxt = _record()
    assert rf.filter(nxt) and "dropped 99995 more times in the previous 60 s" in str(nxt.msg)
