"""This service as one gateway of a fleet: it registers in the shared store, beats its heart, reports the wearables
it sees, and takes a device's lease before it runs a session, a verification or a write on it, so two gateways
never work on one wearable at once (``server.store.fleet``)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable

from calib import __version__

from .clock import ClockWatch
from .config import GatewaySettings
from .store import Lease, Store

log = logging.getLogger(__name__)

WRITE_HOLDER = "write"  # the lease holder of a write-back (it has no id of its own)


class GatewayAgent:
    """The gateway's side of the fleet tables: registration, heartbeat, leases."""

    def __init__(self, store: Store, settings: GatewaySettings, seen: Callable[[], dict[str, int | None]],
                 held: Callable[[], dict[str, str]], changed: Callable[[str, str | None], None], clock: ClockWatch) -> None:
        self.store = store
        self.settings = settings
        self.name = settings.name
        self._seen = seen  # device id -> signal strength (dBm) of the wearables this gateway reaches now
        self._held = held  # device id -> holder of what this gateway runs on it now
        self._changed = changed  # tells the fleet's pages what changed (server.fleet_events)
        self._clock = clock  # measured at every heartbeat: a clock drifting off the database's is said as it happens
        self._reported: frozenset[str] | None = None  # the wearables the last heartbeat said it sees
        self._task: asyncio.Task[None] | None = None
        self._releasing: set[asyncio.Task[None]] = set()

    async def start(self) -> None:
        """Register (again, after a restart), then beat the heart in the background."""
        await asyncio.to_thread(self.store.register_gateway, self.name, self.settings.url, __version__)
        await self.beat()
        self._changed("gateway", None)
        self._task = asyncio.get_running_loop().create_task(self._beat_forever())

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task

    async def beat(self) -> None:
        """One heartbeat: alive, what it sees, its leases renewed (only those it still uses), expired ones swept."""
        held, seen = self._held(), self._seen()
        await asyncio.to_thread(self.store.heartbeat, self.name, self.settings.lease_s, seen, held)
        await self._clock.measure(self.store)
        if frozenset(seen) != self._reported:  # what it runs is announced as it starts and ends, not here
            self._reported = frozenset(seen)
            self._changed("sightings", None)
        for lease in await asyncio.to_thread(self.store.sweep_expired_leases):
            log.warning("gateway %r lost its lease on %s (holder %s): the device is free again", lease.gateway, lease.device_id,
                        lease.holder)
            self._changed("lease", lease.device_id)

    async def _beat_forever(self) -> None:
        while True:
            await asyncio.sleep(self.settings.heartbeat_s)
            try:
                await self.beat()
            except Exception as exc:  # the database away: keep trying; leases run out if it stays away
                log.warning("gateway %r heartbeat failed: %s", self.name, exc)

    async def take(self, device_id: str, holder: str | None) -> Lease:
        """The device's lease for ``holder`` (a session's or verification's id; None: a write) here, or the lease of the
        gateway that holds it. The fleet hears of it from the caller, once what holds the device is recorded
        (``server.api.views.claim_device``)."""
        return await asyncio.to_thread(self.store.take_lease, device_id, self.name, holder or WRITE_HOLDER, self.settings.lease_s)

    def release(self, device_id: str, holder: str | None) -> None:
        """Give the lease back in the background; if that fails, it expires (the heartbeat no longer renews it)."""
        async def release() -> None:
            try:
                await asyncio.to_thread(self.store.release_lease, device_id, self.name, holder or WRITE_HOLDER)
                self._changed("lease", device_id)
            except Exception as exc:
                log.warning("releasing the lease on %s failed (%s); the next heartbeat drops it", device_id, exc)

        with contextlib.suppress(RuntimeError):  # no running loop: the service is stopping, the lease expires
            task = asyncio.get_running_loop().create_task(release())
            self._releasing.add(task)
            task.add_done_callback(self._releasing.discard)
