"""Request throttles held in the service's memory: growing delays after failed sign-ins, and a token
bucket for anonymous analysis requests. Both are per process (a restart forgets them)."""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass


@dataclass
class _Failures:
    count: int = 0
    last: float = 0.0


class SignInThrottle:
    """After ``free`` failed sign-ins for a key (an operator name, a client address), each further attempt must
    wait 2^(n - free) seconds after the last failure, up to ``max_delay_s``; a success clears the key. Keys whose
    last failure is older than ``forget_s`` are forgotten; at most ``keys`` are kept."""

    def __init__(self, free: int, max_delay_s: float = 300.0, forget_s: float = 3600.0, keys: int = 10_000,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.free = free
        self.max_delay_s = max_delay_s
        self.forget_s = forget_s
        self.keys = keys
        self.clock = clock
        self._f: OrderedDict[str, _Failures] = OrderedDict()

    def delay_s(self, failures: int) -> float:
        """The wait imposed after this many consecutive failures."""
        return 0.0 if failures < self.free else min(self.max_delay_s, 2.0 ** (failures - self.free))

    def retry_after(self, key: str) -> float:
        """Seconds until the key may try again (0: now)."""
        f = self._f.get(key)
        if f is None:
            return 0.0
        now = self.clock()
        if now - f.last > self.forget_s:
            del self._f[key]
            return 0.0
        return max(0.0, f.last + self.delay_s(f.count) - now)

    def failed(self, key: str) -> None:
        f = self._f.pop(key, None) or _Failures()
        f.count += 1
        f.last = self.clock()
        self._f[key] = f
        while len(self._f) > self.keys:
            self._f.popitem(last=False)

    def succeeded(self, key: str) -> None:
        self._f.pop(key, None)

    def failures(self, key: str) -> int:
        f = self._f.get(key)
        return 0 if f is None else f.count


class TokenBucket:
    """``rate_per_min`` requests a minute per key, bursts of up to ``burst``."""

    def __init__(self, rate_per_min: float, burst: int, keys: int = 10_000, clock: Callable[[], float] = time.monotonic) -> None:
        self.rate = rate_per_min / 60.0
        self.burst = burst
        self.keys = keys
        self.clock = clock
        self._b: OrderedDict[str, tuple[float, float]] = OrderedDict()  # key -> (tokens, when)

    def take(self, key: str) -> float:
        """Take one token: 0 if allowed, else the seconds until one is free."""
        now = self.clock()
        tokens, when = self._b.pop(key, (float(self.burst), now))
        tokens = min(float(self.burst), tokens + (now - when) * self.rate)
        wait = 0.0
        if tokens >= 1.0:
            tokens -= 1.0
        else:
            wait = (1.0 - tokens) / self.rate
        self._b[key] = (tokens, now)
        while len(self._b) > self.keys:
            self._b.popitem(last=False)
        return wait


def retry_after_header(seconds: float) -> dict[str, str]:
    return {"Retry-After": str(max(1, math.ceil(seconds)))}
