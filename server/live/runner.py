"""Runs one guided session: the device's link in, the state machine, the estimator, the store out.

The runner owns three tasks: the sample pump (link -> state machine), the watchdog (reconnection limit, silence,
overall time limit) and the final step (estimator in a worker, or the kit's calibration together (server.live.kit_session),
then the recording and the outcome written to the store). Whatever happens, the session reaches an end state.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import replace
from datetime import datetime
from typing import TYPE_CHECKING, Any

from calib.apply.identity import SensorIdentity
from calib.io.sections import section_list
from calib.result import CalibrationResult

from ..config import Settings
from ..devices import Device, model_facts, sensor_identity
from ..store import SessionEnd, Store, utcnow
from ..workers.compute import ComputePool, calibrate_live, off_loop
from . import firmware_guidance as firmware_says
from . import guidance as say
from .codes import EndReason
from .events import Broadcaster, Event
from .history import calibration_history, failed_last_time
from .persistence import Persistence
from .session import GuidedSession
from .snapshot_schema import SessionOut
from .stream_faults import MalformedWatch, refused_by_reason

if TYPE_CHECKING:
    from .kit_session import KitSession

log = logging.getLogger(__name__)

WATCHDOG_PERIOD_S = 0.25
SERVICE_LATE_S = 0.75  # the watchdog woke this much later than it asked: the service itself was not running


def compute_result(session: GuidedSession) -> CalibrationResult:
    """Run the estimator on a session's recording and stages, in this process (tests, tools)."""
    outcome = calibrate_live(session.recording(), session.method, session.protocol_stages(), session.heading_prior_deg)
    if outcome.result is None:
        from calib.errors import CalibrationError

        raise CalibrationError(str(outcome.refusal), code=outcome.code)
    return outcome.result


class LiveSession(Persistence):
    """A guided session on a connected device, with its event stream."""

    def __init__(
        self,
        machine: GuidedSession,
        device: Device,
        store: Store,
        settings: Settings,
        software_version: str,
        operator: str,
        on_end: Callable[[LiveSession], None] | None = None,
        pool: ComputePool | None = None,
        relay: Callable[[str, Event], None] | None = None,
    ) -> None:
        self.pool = pool
        self.relay = relay  # hands each snapshot on to other gateways' followers (server.fleet_events)
        self.machine = machine
        self.device = device
        self.store = store
        self.settings = settings
        self.software_version = software_version
        self.operator = operator
        self.broadcaster = Broadcaster()
        machine.listener = self._on_snapshot
        self.on_end = on_end
        self.recording_sha256: str | None = None
        self._csv: bytes | None = None  # the recording a result was computed on, as native CSV
        self._csv_samples = 0  # how many samples it holds
        self._sections: list[dict[str, str | int]] | None = None  # the stages the estimator was given, as a section list
        self._task: asyncio.Task[None] | None = None
        self._pump: asyncio.Task[None] | None = None
        self._changed: asyncio.Future[None] | None = None  # resolved by the next snapshot (the state may have changed)
        self._last_sample_mono = time.monotonic()
        self._link_down = False  # the link said it dropped (a LinkEvent), until it says it is back
        self._silent = False  # the watchdog found no data for link_silence_s, until data comes again
        self._refused_at_sample: dict[str, int] = {}  # the link's refused packets by reason, at the last sample
        self._malformed = MalformedWatch()  # packets refused as malformed since the stream started
        self.persisted = False
        self.persist_error: str | None = None  # why the last write to the store failed, until one succeeds
        self._retry: asyncio.Task[None] | None = None  # writing the outcome again while the store cannot take it
        self.identity: SensorIdentity | None = None  # the sensor, its power-up and temperature, once connected
        self.temperatures_c: tuple[float, float] | None = None  # at the session's start and end
        self._spooled = 0  # samples of the buffer made durable in the store's spool
        self._spool_chunk = 0
        self._spool_write: asyncio.Future[None] | None = None  # the spool's write under way
        self.kit: KitSession | None = None  # the kit this wearable is calibrated with (server.live.kit_session)

    @property
    def id(self) -> str:
        return self.machine.id

    def _on_snapshot(self, event: str, snapshot: SessionOut) -> None:
        if self._changed is not None and not self._changed.done():
            self._changed.set_result(None)
        published = self.broadcaster.publish(event, snapshot)
        if self.relay is not None:
            self.relay(self.id, published)
        if self.kit is not None:
            self.kit.member_changed()

    def start(self) -> None:
        # publish the first snapshot (connecting) before anyone can subscribe to the stream
        self.machine.publish()
        self._task = asyncio.get_running_loop().create_task(self._run(), name=f"session-{self.id}")

    async def wait(self) -> None:
        if self._task is not None:
            with contextlib.suppress(asyncio.CancelledError):
                await asyncio.shield(self._task)

    def cancel(self, reason: str = "Cancelled by the operator.") -> bool:
        ok = self.machine.cancel(reason)
        if ok and self._pump is not None:
            self._pump.cancel()
        if ok and self.kit is not None:
            self.kit.left(self)  # no longer waits for the kit's calibration
        return ok

    async def shutdown(self) -> None:  # the service stops: end the session (cancelled) and wait for it to be written
        self.cancel("The service was stopped during the calibration.")
        await self.wait()
        self.broadcaster.close()

    def release(self) -> None:
        """The service forgets this ended session: break the references between it, its machine and its tasks so that
        it is freed at once, not at the garbage collector's next full pass (server.memory)."""
        self.machine.listener = None
        self._task = self._pump = self._retry = None
        self.on_end = None
        self.relay = None

    # -- the session's life -------------------------------------------------------------------
    async def _run(self) -> None:
        m = self.machine
        watchdog = asyncio.get_running_loop().create_task(self._watchdog())
        spool = asyncio.get_running_loop().create_task(self._spool_loop())
        try:
            self._pump = asyncio.get_running_loop().create_task(self._stream())
            # the link streams on while the result is computed: a turn the result asks again follows at once
            while await self._until_computing():
                await self._compute()
            if self._pump is not None and not self._pump.done():
                self._pump.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._pump
            await self._stop_link()
            await self._note_end_temperature()
            if not m.finished:
                # the stream ended without an end state (device stopped streaming)
                m.fail("link_lost", say.stream_stopped())
        except Exception as exc:  # the last line of defence: an end state, never a hanging session
            log.exception("session %s failed", self.id)
            m.fail("internal_error", say.internal_error(f"{type(exc).__name__}: {exc}"))
        finally:
            for task in (watchdog, spool):
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await task
            await self._stop_link()
            await self._spool_settled()
            await self._persist()
            # the stream stays open for the accept/discard event, then ends (clients see an end state)
            asyncio.get_running_loop().call_later(self.settings.sse_linger_s, self.broadcaster.close)
            if self.on_end is not None:
                self.on_end(self)

    async def _until_computing(self) -> bool:
        """Wait until the session has a recording to compute (True) or has ended, or its stream has (False)."""
        m, pump = self.machine, self._pump
        while not m.finished and m.state != "computing" and pump is not None and not pump.done():
            # a plain future the next snapshot resolves: no task of its own, so nothing outlives the session
            self._changed = asyncio.get_running_loop().create_future()
            try:
                await asyncio.wait({pump, self._changed}, return_when=asyncio.FIRST_COMPLETED)
            finally:
                self._changed = None
        return m.state == "computing"

    async def _stream(self) -> None:
        m = self.machine
        dev = self.device
        link = dev.get_link()
        m.stream.time_scale = float(getattr(link.clock, "scale", 1.0))  # a simulated wearable's clock may run faster
        try:
            if not getattr(link, "connected", False):
                await link.connect()
            info = await link.read_info()
        except Exception as exc:
            m.fail("connect_failed", say.connect_failed(str(exc) or type(exc).__name__))
            return
        cfg = info.config
        dev.info.update(
            {
                "sensor_model": info.model,
                "firmware": info.firmware,
                "serial": info.serial,
                "manufacturer": info.manufacturer,
                "battery_pct": info.battery_pct,
                "accel_range_g": cfg.accel_range_g,
                **(info.power_up.to_dict() if info.power_up else {}),
                # the model, its limits, and the rate and range read from the device
                **model_facts(info.device_model, {"sample_rate_hz": cfg.sample_rate_hz,
                                                  "gyro_full_scale_dps": cfg.gyro_full_scale_dps}),
            }
        )
        if info.name:
            dev.name = info.name
        with contextlib.suppress(Exception):
            await asyncio.to_thread(
                self.store.upsert_device, dev.id, name=dev.name, address=dev.address, transport=dev.transport,
                sensor_model=info.model, firmware=info.firmware, serial=info.serial,
                power_up=info.power_up.to_dict() if info.power_up else None,
            )
        self.identity = sensor_identity(dev.id, info)
        await dev.note_held(link, self.store)
        m.connected(cfg.sample_rate_hz, dict(dev.info), float(cfg.gyro_full_scale_dps))
        try:
            await link.start()
        except Exception as exc:
            m.fail("connect_failed", say.connect_failed(f"the stream did not start: {exc}"))
            return
        self._last_sample_mono = time.monotonic()
        self._refused_at_sample = self._refused_now()  # a link kept from an earlier session brings its own counts
        self._malformed.start(getattr(link, "stats", None))
        async for item in link.samples():
            kind = getattr(item, "kind", None)
            if kind is not None:
                self._on_link_event(item)
            else:
                self._last_sample_mono = time.monotonic()
                self._refused_at_sample = self._refused_now()
                if self._link_down:
                    self._link_down = False
                    m.link_restored()
                if self._silent:
                    # whether the silence lost anything is read from the samples, never from the service's clock
                    self._silent = False
                    m.data_resumed(int(item.lost_before))
                m.fs_estimate, m.fs_rel_std = (float(item.fs_hz) if item.fs_hz else m.fs_estimate), item.fs_rel_std
                m.feed(item.t_device_s, item.gyro_dps, item.accel_g, item.seq, int(item.lost_before), time.time(),
                       link.clock(), int(item.refused_before))
                malformed = self._malformed.verdict(getattr(link, "stats", None), dev.info.get("firmware"))
                if not m.finished and malformed is not None:
                    m.fail(EndReason.UNREADABLE_DATA, malformed)
            if m.finished:
                return

    async def _note_end_temperature(self) -> None:
        """The sensor's temperature over the session: the mean of its readings at the start and at the end."""
        link, start = self.device.link, self.identity
        if link is None or start is None or start.temperature_c is None or not getattr(link, "connected", False):
            return
        with contextlib.suppress(Exception):
            end = await asyncio.wait_for(link.read_power_up(), timeout=5.0)
            if end is not None and end.temperature_c is not None:
                self.temperatures_c = (start.temperature_c, end.temperature_c)
                self.identity = replace(start, temperature_c=round((start.temperature_c + end.temperature_c) / 2, 2))

    def _on_link_event(self, ev: Any) -> None:
        m = self.machine
        if ev.kind == "link_lost":
            self._link_down = True
            m.link_lost()
        elif ev.kind == "link_restored":
            self._link_down = False
            m.link_restored()
        elif ev.kind == "link_failed":
            m.fail("link_lost", say.link_lost(self.settings.reconnect_timeout_s))
        elif ev.kind == "stream_ended":
            m.fail("link_lost", say.stream_stopped())

    async def _watchdog(self) -> None:
        """The wall-clock limits, the service's own lateness, and silence from a link that says it is up."""
        m = self.machine
        due = time.monotonic() + WATCHDOG_PERIOD_S
        while not m.finished:
            await asyncio.sleep(max(0.0, due - time.monotonic()))
            now = time.monotonic()
            late = now - due
            due = now + WATCHDOG_PERIOD_S
            if late > SERVICE_LATE_S:
                # the process did not run (starved of CPU, stopped, a blocked loop): time it says nothing of the
                # link or the hand, so the silence and the limits do not count it
                self._last_sample_mono += late
                m.service_was_late(late)
            m.tick()
            if m.finished or self._silent or self._link_down or m.state in ("connecting", "computing", "reconnecting"):
                continue
            arrived = getattr(self.device.link, "last_data_mono", None)
            last = max(self._last_sample_mono, arrived or 0.0)  # samples waiting to be read are not silence
            if now - last > self.settings.link_silence_s:
                refused = self._refused_since_last_sample()
                if refused:  # packets come, none of them readable: the wearable speaks another format
                    m.fail(EndReason.UNREADABLE_DATA, firmware_says.unreadable_data(refused, self.device.info.get("firmware")))
                    continue
                self._silent = True
                m.data_silent(now - last)
        if self._pump is not None and not self._pump.done():
            self._pump.cancel()

    def _refused_now(self) -> dict[str, int]:
        """The packets the link has refused so far, by reason (server.link: LinkStats.malformed_reasons)."""
        return refused_by_reason(getattr(self.device.link, "stats", None))

    def _refused_since_last_sample(self) -> dict[str, int]:
        """The packets the link refused since the last sample it could read, by reason."""
        before = self._refused_at_sample
        return {r: c - before.get(r, 0) for r, c in self._refused_now().items() if c > before.get(r, 0)}

    async def _compute(self) -> None:
        m = self.machine
        rec, stages = m.recording(), m.protocol_stages()
        self._sections = section_list(stages)
        if self.kit is not None:  # calibrated with the rest of its kit, once every wearable's recording is in
            kit_outcome = await self.kit.outcome_for(self, rec, stages)
            if kit_outcome is None:  # the kit's calibration asked the tray a turn again: this guidance asks it
                return
            outcome = kit_outcome
        else:
            job = off_loop(self.pool, calibrate_live, rec, m.method, stages, m.heading_prior_deg)
            try:
                outcome = await asyncio.wait_for(job, timeout=self.settings.compute_timeout_s)
            except TimeoutError:
                m.fail(EndReason.SERVICE_OVERLOADED, say.compute_timeout(self.settings.compute_timeout_s))
                return
        self._csv, self._csv_samples = outcome.csv, len(rec)
        if outcome.result is None:
            m.fail(outcome.end, outcome.refusal or say.internal_error("no result and no reason"))
            return
        result = outcome.result
        try:
            history = await asyncio.to_thread(calibration_history, self.store, m.device_id)
            failed_before = await asyncio.to_thread(failed_last_time, self.store, m.device_id)
        except Exception:  # the store's history only adds a caution: a result stands without it
            log.warning("the history of %s could not be read to compare the new calibration with", m.device_id, exc_info=True)
            history, failed_before = [], set()
        m.set_result(result, history, failed_before,  # a kit's tray is not turned again for one wearable
                     can_redo=self.kit is None and self.streaming)

    async def _stop_link(self) -> None:
        if (link := self.device.link) is None:
            return
        with contextlib.suppress(Exception):
            await asyncio.wait_for(link.stop(), timeout=5.0)

    def session_end(self) -> SessionEnd:
        """The session as it ended (an accept writes this if the end-of-session write was lost)."""
        m = self.machine
        ended = datetime.fromisoformat(m.ended_at) if m.ended_at else utcnow()
        return SessionEnd(
            state=m.state, reason_code=m.reason_code, reason=m.reason, result=m.result, passed=m.passed, ended_at=ended,
            info={"lost_samples": m.lost_samples, "refused_samples": m.refused_samples, "service_late_s": round(m.service_late_s, 3),
                  "warnings": [w.model_dump() for w in m.warnings],
                  "turns": {a: t.to_dict() for a, t in m.turns.items()},
                  "checks": [] if m.judgement is None else m.judgement.checks_json(),
                  "departures": [] if m.judgement is None else m.judgement.departures_json(),
                  "accuracy": None if m.judgement is None else m.judgement.accuracy, "samples": m.buf.n, "sample_rate_hz": m.fs,
                  "gyro_full_scale_dps": m.full_scale, "identity": self.identity.to_json() if self.identity else None,
                  "temperatures_c": self.temperatures_c, "sections": self._sections, "kit_id": m.kit_id},
        )

    @property
    def streaming(self) -> bool:
        """Whether its link still streams, so that a turn asked again can follow."""
        return self._pump is not None and not self._pump.done()

    @property
    def csv_bytes(self) -> bytes | None:
        """The recording the session's result was computed on, as native CSV (None before a computation)."""
        return self._csv

    @property
    def csv_samples(self) -> int:
        """How many samples ``csv_bytes`` holds: what the store's row of it says."""
        return self._csv_samples

    @property
    def sections(self) -> list[dict[str, str | int]] | None:
        """The rests and turns the session's calibration was computed on, as imucal's section list (None: it ended
        before it was calibrated)."""
        return self._sections

