"""The service: everything the API works with (settings, store, operators and their sign-ins, devices, the
worker pools, live sessions) and what it does at start and stop."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from datetime import UTC, datetime

from .auth import Authenticator, SignIns
from .clock import ClockWatch
from .config import Settings
from .devices import DeviceManager
from .fleet_events import FleetEvents
from .gateway import WRITE_HOLDER, GatewayAgent
from .live.kit_session import KitSession
from .live.runner import LiveSession
from .live.snapshot import stored_snapshot
from .live.snapshot_schema import SessionOut
from .live.verify_run import VerifyRun
from .memory import TRIM_PERIOD_S, release_free_memory
from .schemas import Integrity
from .store import Store
from .throttle import TokenBucket
from .workers.compute import ComputePool

log = logging.getLogger(__name__)

KEEP_FINISHED = 200  # finished live sessions kept in memory for their event streams
MIN_FREE_BYTES = 20_000_000  # a session's recording and rows, many times over: below this no session is started
KEEP_VERIFY_RUNS = 50  # ended live verifications answered at GET /verifications/{id}


class Service:
    """Everything the API works with: settings, store, operators, devices, live sessions."""

    def __init__(self, settings: Settings, store: Store | None = None, devices: DeviceManager | None = None) -> None:
        self.settings = settings
        self.store = store or Store(settings.db_url)
        self.auth = Authenticator(self.store, settings.api_token, settings.token_ttl_s)
        self.sign_ins = SignIns(self.auth, settings.pin_from)
        self.anonymous_analyses = TokenBucket(settings.anonymous_analyses_per_min, burst=3)
        self.devices = devices or DeviceManager()
        self.pool = ComputePool(memory_mb=settings.worker_memory_mb)
        self.sessions: dict[str, LiveSession] = {}
        self.kits: dict[str, KitSession[LiveSession]] = {}  # kit sessions, by id: their wearables' sessions are in ``sessions``
        self.active: dict[str, str] = {}  # device id -> running session id
        self.writing: set[str] = set()  # devices a calibration is being written to
        self.verify_runs: dict[str, VerifyRun] = {}  # live verification turns, by id (kept after they end, for the page)
        self.events = FleetEvents(settings.db_url, self.session_as_stored, self.decided_elsewhere)
        self.clock = ClockWatch()  # how far this computer's clock is from the store's
        self.gateway = (GatewayAgent(self.store, settings.gateway, seen=self._seen, held=self._held,
                                     changed=self.events.fleet_changed, clock=self.clock)
                        if settings.gateway is not None else None)
        self.started = time.time()
        self.integrity: Integrity | None = None  # the last verification of the store's hash chains
        self._integrity_task: asyncio.Task[None] | None = None
        self._trim_task: asyncio.Task[None] | None = None
        self._freed = False  # sessions ended since the allocator last gave memory back

    async def verify_store(self) -> Integrity:
        """Verify the store's hash chains now (in a thread); the result is what /health reports."""
        report = await asyncio.to_thread(self.store.verify)
        self.integrity = Integrity(ok=report.ok, rows=report.rows, first_broken_link=report.broken,
                                   checked_at=datetime.now(UTC).isoformat())
        if not report.ok:
            log.error("the store's history was tampered with: %s", report.broken)
        return self.integrity

    async def _trim_periodically(self) -> None:
        while True:
            await asyncio.sleep(TRIM_PERIOD_S)
            if self._freed:
                self._freed = False
                await asyncio.to_thread(release_free_memory)

    async def _verify_periodically(self) -> None:
        while True:
            with contextlib.suppress(Exception):
                await self.verify_store()
            await asyncio.sleep(self.settings.integrity_check_s)

    async def startup(self) -> None:
        await self.pool.start()
        n = await asyncio.to_thread(
            self.store.fail_unfinished_sessions,
            "The service was restarted while this calibration ran. Start a new calibration.",
            self.gateway_name,
        )
        if n:
            log.warning("%d sessions left open by a previous run were marked failed", n)
        # the first check of the history runs after the recovery above, so it counts the recordings it archived
        self._integrity_task = asyncio.get_running_loop().create_task(self._verify_periodically())
        self._trim_task = asyncio.get_running_loop().create_task(self._trim_periodically())
        for dev in self.devices.devices.values():
            await asyncio.to_thread(self.store.upsert_device, dev.id, name=dev.name, address=dev.address, transport=dev.transport)
        await self.events.start()
        if self.gateway is not None:
            await self.gateway.start()  # its first heartbeat measures the clock, and every one after it
        else:
            await self.clock.measure(self.store)

    @property
    def gateway_name(self) -> str | None:
        """This service's name in the fleet (None: a service on its own)."""
        return None if self.gateway is None else self.gateway.name

    def _seen(self) -> dict[str, int | None]:
        """The wearables this service reaches now, with their last signal strength (dBm) when the radio gave one."""
        return {d.id: d.info.get("rssi") for d in self.devices.devices.values()}

    def _held(self) -> dict[str, str]:
        """What this service runs on which device now: a session's or verification's id, or a write."""
        return {**{d: WRITE_HOLDER for d in self.writing}, **self.active}

    def session_as_stored(self, session_id: str) -> SessionOut | None:
        """A session as the store keeps it (None: the store has no such session)."""
        row = self.store.session(session_id)
        return None if row is None else stored_snapshot(row)

    def decided_elsewhere(self, session_id: str, stored: SessionOut) -> None:
        """A session running here was accepted or discarded on another gateway: its pages here show the decision."""
        live = self.sessions.get(session_id)
        if live is not None and live.machine.decision is None and stored.decision is not None:
            live.machine.decide(stored.decision, None)
            live.broadcaster.close()

    def release_device(self, device_id: str, holder: str | None) -> None:
        """The session or verification ``holder`` (None: the write) is done with the device: free it here and in the
        fleet."""
        if holder is None:
            self.writing.discard(device_id)
        elif self.active.get(device_id) == holder:
            del self.active[device_id]
        else:
            return
        if self.gateway is not None:
            self.gateway.release(device_id, holder)
        else:
            self.events.fleet_changed("release", device_id)

    async def shutdown(self) -> None:
        for task in (self._integrity_task, self._trim_task):
            if task is not None:
                task.cancel()
        if self.gateway is not None:
            await self.gateway.stop()
        await self.events.stop()
        for run in list(self.verify_runs.values()):
            run.cancel()
            await run.wait()
        for live in list(self.sessions.values()):
            if not live.machine.finished:
                with contextlib.suppress(Exception):
                    await asyncio.wait_for(live.shutdown(), timeout=10.0)
            with contextlib.suppress(Exception):
                await asyncio.wait_for(live.stop_retrying(), timeout=10.0)
            live.broadcaster.close()
        await self.devices.close()
        self.sign_ins.close()
        self.pool.shutdown()
        self.store.close()

    def verification_ended(self, run: VerifyRun) -> None:
        """Free the device; keep the newest KEEP_VERIFY_RUNS ended runs for pages still polling (they are in the store)."""
        self.release_device(run.device.id, run.id)
        ended = [rid for rid, r in self.verify_runs.items() if r.state in ("done", "failed")]
        for rid in ended[:-KEEP_VERIFY_RUNS]:  # dicts keep insertion order: the oldest first
            del self.verify_runs[rid]

    def storage_problem(self) -> str | None:
        """Why a new session could not be kept now (the store's disk full or nearly, finished sessions still waiting
        to be written), in an operator's words; None when it can."""
        waiting = self.unstored()
        if waiting:
            return (f"{len(waiting)} finished calibration{'s' if len(waiting) > 1 else ''} could not be written to the "
                    f"store yet: {waiting[0].persist_error}. Start again once it has taken them")
        free = self.store.free_bytes()
        if free is not None and free < MIN_FREE_BYTES:
            return (f"the disk holding the store ({self.store.display_url}) has {free / 1e6:.1f} MB free, less than a "
                    f"calibration needs ({MIN_FREE_BYTES / 1e6:.0f} MB): free space there, then start again")
        return None  # a database whose space this service cannot see: the session's first write says whether it fits

    def storage_warnings(self) -> list[str]:
        """What /health says of the store's space: the blockers above, or a write that failed for a full disk."""
        if (problem := self.storage_problem()) is not None:
            return [f"the store cannot take new calibrations: {problem}"]
        if self.store.full_since is not None:
            since = datetime.fromtimestamp(self.store.full_since, UTC).isoformat(timespec="seconds")
            return [f"the disk holding the store was full at the last write ({since}); the next write says whether space "
                    "has been freed"]
        return []

    def unstored(self) -> list[LiveSession]:
        """Finished sessions whose outcome the store refused (kept here, written again until it takes them). One whose
        first write is still under way is not among them: nothing has failed yet."""
        return [s for s in self.sessions.values() if s.machine.finished and not s.persisted and s.persist_error is not None]

    def _session_ended(self, live: LiveSession) -> None:
        self.release_device(live.device.id, live.id)
        finished = [s for s in self.sessions.values() if s.machine.finished and s.persisted]
        for old in finished[: max(0, len(finished) - KEEP_FINISHED)]:
            old.broadcaster.close()
            self.sessions.pop(old.id, None)
            self.events.session_over(old.id)
            old.release()
        self._freed = True  # what the ended sessions freed goes back to the system at the next trim (server.memory)
