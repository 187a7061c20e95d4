"""A log that says a repeated error a few times and then how often it repeated, never a million times.

When the process runs out of a resource (file descriptors, disk), the same error comes from the same place in a
tight loop; written out each time it fills the disk the service then needs. ``RepeatFilter`` lets the first
``burst`` copies of a message through in each ``window_s``, drops the rest, and when the window ends writes one
line saying how many were dropped.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

DEFAULT_BURST = 5
DEFAULT_WINDOW_S = 60.0


class RepeatFilter(logging.Filter):
    """Drops copies of one message (same logger, level, text and exception type) beyond ``burst`` per ``window_s``."""

    def __init__(self, burst: int = DEFAULT_BURST, window_s: float = DEFAULT_WINDOW_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__()
        self.burst = burst
        self.window_s = window_s
        self._clock = clock
        self._seen: dict[tuple[object, ...], list[float]] = {}  # key -> [window start, copies let through, dropped]

    def filter(self, record: logging.LogRecord) -> bool:
        now = self._clock()
        exc = record.exc_info[0].__name__ if record.exc_info and record.exc_info[0] else None
        key = (record.name, record.levelno, str(record.msg), exc)
        entry = self._seen.get(key)
        if entry is None or now - entry[0] >= self.window_s:
            dropped = 0 if entry is None else int(entry[2])
            self._seen[key] = [now, 1, 0]
            if dropped:  # the summary of the window that ended rides on the first copy of the next
                record.msg = f"{record.msg} [the same message was dropped {dropped} more times in the previous {self.window_s:g} s]"
            if len(self._seen) > 10_000:  # many distinct messages: forget windows that ended
                self._seen = {k: v for k, v in self._seen.items() if now - v[0] < self.window_s}
            return True
        if entry[1] < self.burst:
            entry[1] += 1
            if entry[1] == self.burst:
                record.msg = f"{record.msg} [repeated {self.burst} times in {self.window_s:g} s: further copies are dropped " \
                             "and counted]"
            return True
        entry[2] += 1
        return False


def install(loggers: tuple[str, ...] = ("", "uvicorn", "uvicorn.access")) -> RepeatFilter:
    """Put one RepeatFilter on every handler of these loggers (the root's catches asyncio's accept errors)."""
    rf = RepeatFilter()
    for name in loggers:
        for handler in logging.getLogger(name).handlers:
            handler.addFilter(rf)
    return rf
