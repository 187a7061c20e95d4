"""The simulated BlueZ run on an event loop of its own, for callers that are not asynchronous."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Iterable
from typing import Any, TypeVar

from wearable_protocol import (
    GattPeripheral,
)

from .bus import BusUnavailable
from .service import SimulatedBlueZ

T = TypeVar("T")


class BlueZThread:
    """The simulated BlueZ with its peripherals on an event loop of its own, in a background thread.

    For tests and benchmarks that run the bleak client in the main thread: ``call(fn, *args)`` runs
    ``fn`` in the device thread (use it for every access to a peripheral) and returns its result.
    """

    def __init__(self, bus_address: str, peripherals: Iterable[GattPeripheral], **options: Any) -> None:
        self.bus_address = bus_address
        self.peripherals = list(peripherals)
        self.options = options
        self.bluez: SimulatedBlueZ | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._stopped: asyncio.Event | None = None

    def start(self) -> BlueZThread:
        self._thread = threading.Thread(target=self._main, name="simulated-bluez", daemon=True)
        self._thread.start()
        self._ready.wait(15)
        if self._error is not None:
            raise self._error
        if not self._ready.is_set():
            raise BusUnavailable("the simulated BlueZ did not start within 15 s")
        return self

    def _main(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._serve())
        except BaseException as e:  # reported to start()
            self._error = e
            self._ready.set()
        finally:
            loop.close()

    async def _serve(self) -> None:
        self._stopped = asyncio.Event()
        self.bluez = SimulatedBlueZ(self.peripherals, **self.options)
        await self.bluez.start(self.bus_address)
        self._ready.set()
        await self._stopped.wait()
        for p in self.peripherals:
            close = getattr(p, "aclose", None)
            if close is not None:
                await close()
        await self.bluez.stop()

    def call(self, fn: Callable[..., T], *args: Any) -> T:
        """Run ``fn(*args)`` on the device loop and return its result."""
        assert self._loop is not None

        async def run() -> T:
            return fn(*args)

        return asyncio.run_coroutine_threadsafe(run(), self._loop).result(10)

    def stop(self) -> None:
        if self._loop is not None and self._stopped is not None and self._thread and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stopped.set)
            self._thread.join(10)

    def __enter__(self) -> BlueZThread:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
