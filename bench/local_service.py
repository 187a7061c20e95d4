"""`gyrocal serve` as the benchmarks start it: a free port, and waiting until the service answers."""

from __future__ import annotations

import atexit
import shutil
import socket
import tempfile
import time
from pathlib import Path

import httpx


def free_port() -> int:
    """A TCP port on this computer no one listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def scratch_dir(prefix: str) -> Path:
    """A new directory under the system's temporary one (a benchmark's store, logs), removed when the benchmark ends."""
    where = Path(tempfile.mkdtemp(prefix=prefix))
    atexit.register(shutil.rmtree, where, True)
    return where


def wait_until_up(client: httpx.Client, timeout_s: float = 30.0) -> None:
    """Return once ``client``'s service answers /health; RuntimeError after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if client.get("/health").status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.1)
    raise RuntimeError(f"the service at {client.base_url} did not answer within {timeout_s:g} s")
