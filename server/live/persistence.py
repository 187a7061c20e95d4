"""Writing a session to the store: its samples as they arrive (the spool), and once finished its outcome, kept until
the store can take it.

``Persistence`` is a part of ``LiveSession`` (server.live.runner); the fields and methods declared here without a
body are the session's.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import TYPE_CHECKING

import numpy as np

from ..store import BINARY_SPOOL, SessionEnd, Store, StoreFull
from ..workers.compute import ComputePool, off_loop, recording_csv

if TYPE_CHECKING:
    from .buffer import SampleBuffer
    from .session import GuidedSession

log = logging.getLogger(__name__)

PERSIST_RETRY_S = 5.0  # a session's outcome the store could not take is written again this often
SPOOL_PERIOD_S = 1.0  # a running session's new samples are made durable this often
SPOOL_MAX_SAMPLES = 600_000  # beyond this (15 min at 562.5 Hz, the longest session) nothing more is spooled


def spool_rows(buf: SampleBuffer, start: int, end: int) -> tuple[str, bytes]:
    """Samples [start, end) of a session's buffer as spool rows: little-endian float64 rows of the columns named after
    the spool's ``f8:`` prefix (t, gx, gy, gz[, ax, ay, az][, seq]); the store turns them into the native CSV they
    would have been only if a crash leaves them to archive (server.store.spool). Formatting every sample of twenty
    wearables as text once a second cost a busy service a twentieth of a core."""
    names, cols = ["t", "gx", "gy", "gz"], [buf.t[start:end, None], buf.gyro[start:end]]
    if buf.accel is not None and buf.has_accel:
        names += ["ax", "ay", "az"]
        cols.append(buf.accel[start:end])
    if buf.has_seq:
        names.append("seq")
        cols.append(buf.seq[start:end, None].astype(np.float64))
    rows = np.ascontiguousarray(np.hstack(cols), dtype="<f8")
    return BINARY_SPOOL + ",".join(names), rows.tobytes()


class Persistence:
    """A session's samples spooled as they arrive, and its outcome and recording once finished, written to the store
    until it takes them."""

    machine: GuidedSession
    store: Store
    pool: ComputePool | None
    operator: str
    recording_sha256: str | None
    persisted: bool
    persist_error: str | None
    _csv: bytes | None
    _csv_samples: int
    _retry: asyncio.Task[None] | None
    _spooled: int  # samples of the buffer made durable in the store's spool
    _spool_chunk: int
    _spool_write: asyncio.Future[None] | None

    @property
    def id(self) -> str:
        raise NotImplementedError

    def session_end(self) -> SessionEnd:
        raise NotImplementedError

    async def _persist(self) -> None:
        """Archive the recording and write the outcome. When the store cannot take them (a full disk, an outage) they
        stay here and are written again every PERSIST_RETRY_S until it can (an accept writes them too)."""
        if not await self._persist_once():
            self._retry = asyncio.get_running_loop().create_task(self._persist_until_stored())

    async def _persist_until_stored(self) -> None:
        while not self.persisted:
            await asyncio.sleep(PERSIST_RETRY_S)
            if await self._persist_once():
                log.info("session %s is written to the store at last", self.id)

    async def _persist_once(self) -> bool:
        m = self.machine
        try:
            # the recording a result was computed on is the one archived with it; a session that went on after its
            # computation (a turn asked again, then a failure or a cancel) is archived whole
            if m.buf.n > 0 and (self._csv is None or (m.result is None and self._csv_samples != m.buf.n)):
                rec = m.recording()
                self._csv, self._csv_samples = await off_loop(self.pool, recording_csv, rec), len(rec)
            if self._csv is not None and self.recording_sha256 is None:
                self.recording_sha256 = await asyncio.to_thread(self.store.archive_recording, self.id, self._csv,
                                                                self._csv_samples)
            stored = await asyncio.to_thread(self.store.finish_session, self.id, self.session_end(),
                                             self.operator if m.state == "cancelled" else None)
            if stored is not None and (stored["state"], stored["reason_code"]) != (m.state, m.reason_code):
                log.warning("session %s ended %s here, but the store had already ended it %s (%s): %s", self.id, m.state,
                            stored["state"], stored["reason_code"], stored["reason"])
            self.persisted = True
            self.persist_error = None
            return True
        except Exception as exc:
            if self.persist_error is None:  # said once; the retries are quiet until they succeed
                log.warning("could not write session %s to the store (kept, retried every %g s): %s", self.id,
                            PERSIST_RETRY_S, exc)
            self.persist_error = (f"{exc}; the session is kept by the service and written when space returns"
                                  if isinstance(exc, StoreFull) else f"{type(exc).__name__}: {exc}")
            return False

    async def stop_retrying(self) -> None:
        """The service stops: one last try to write an outcome the store could not take, then say it is lost."""
        if self._retry is None or self.persisted:
            return
        self._retry.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self._retry
        if not await self._persist_once():
            log.error("session %s (%s) could not be written to the store before the service stopped: %s", self.id,
                      self.machine.state, self.persist_error)

    async def _spool_loop(self) -> None:
        """Append the samples received since the last round to the store's spool, once a second."""
        while True:
            await asyncio.sleep(SPOOL_PERIOD_S)
            await self._spool()

    async def _spool_settled(self) -> None:
        """Wait for a spool write still under way (its task was cancelled, its thread was not)."""
        if self._spool_write is not None:
            with contextlib.suppress(Exception, asyncio.CancelledError):
                await self._spool_write

    async def _spool(self) -> None:
        buf = self.machine.buf
        end = min(buf.n, SPOOL_MAX_SAMPLES)
        if end <= self._spooled:
            return
        columns, rows = spool_rows(buf, self._spooled, end)
        # the write runs on in its thread when this task is cancelled (the session ended): kept, so that the end waits
        # for it before the recording is archived and the spool cleared, and no spooled row is left behind
        self._spool_write = asyncio.ensure_future(
            asyncio.to_thread(self.store.spool_samples, self.id, self._spool_chunk, columns, rows, end - self._spooled))
        try:
            await asyncio.shield(self._spool_write)
        except Exception as exc:  # the store is down: these samples are spooled with the next round
            log.warning("could not spool the samples of session %s: %s", self.id, exc)
            return
        self._spool_chunk += 1
        self._spooled = end
