"""Giving freed memory back (server.memory): glibc's malloc_trim found in the process's own C library, without
starting a process to look for it (the service, and every compute worker, imports it as it starts)."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest
from server_fixtures import ROOT

WATCH_SPAWNS = """
import subprocess
started = []
real = subprocess.Popen.__init__
def watched(self, args, *a, **k):
    started.append(args)
    real(self, args, *a, **k)
subprocess.Popen.__init__ = watched
import server.memory
print(server.memory.release_free_memory(), started)
"""


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="malloc_trim is glibc's")
def test_free_memory_is_returned_through_glibc_without_starting_a_process() -> None:
    out = subprocess.run([sys.executable, "-c", WATCH_SPAWNS], cwd=ROOT, capture_output=True, text=True, timeout=60,
                         check=True)
    assert out.stdout.strip() == "True []", out.stdout
