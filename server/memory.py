"""Giving freed memory back to the operating system.

An ended session is freed as soon as the service forgets it (``LiveSession.release`` breaks its reference cycles;
before, each waited for the garbage collector's rare full pass with its sample buffers, and 1,000 sessions started
and cancelled took the service from 157 MB to 607 MB). What the freed sessions leave in glibc's heap is returned
by ``release_free_memory`` (malloc_trim), which the service calls every TRIM_PERIOD_S after sessions have ended, in
a worker thread: over 800 sessions past the first 200, +2 MB with it, +8 MB without (bench/session_churn.py).
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable

TRIM_PERIOD_S = 5.0


def _malloc_trim() -> Callable[[int], int] | None:
    # the C library the process already runs on (dlopen of the program itself): ctypes.util.find_library would run
    # ldconfig, or a C compiler where there is none, in every process that imports this
    try:
        return ctypes.CDLL(None).malloc_trim  # glibc only; other allocators return memory by themselves
    except (OSError, AttributeError):
        return None


_TRIM = _malloc_trim()


def release_free_memory() -> bool:
    """Return the allocator's free memory to the system (glibc's malloc_trim); whether the allocator offers it."""
    if _TRIM is None:
        return False
    _TRIM(0)
    return True
