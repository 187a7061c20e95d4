"""Model checks (calib.diagnosis) for the service: worker processes, a bounded queue and a result cache.

A diagnosis simulates the recording a few hundred times: about a second for a 30 s recording, up to
a minute for a long one. It runs in its own worker processes (not the estimator's pool, so a live
session's result never waits behind it), at most ``workers`` at once with ``max_waiting`` more
queued; beyond that the service is busy (``Busy``). A diagnosis over its time limit has its worker
killed (the next one starts a fresh worker), so a runaway recording cannot hold the CPU. Workers report
progress through their pipe. Results are kept in memory by the SHA-256 of what was diagnosed, so asking
again is instant; requests for a diagnosis already running wait for that one.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import json
import logging
import multiprocessing
import os
import signal
import tempfile
import time
from collections import OrderedDict
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

if TYPE_CHECKING:
    from calib.io.inputs import RecordingInput

log = logging.getLogger(__name__)

DEFAULT_WORKERS = max(1, min(2, (os.cpu_count() or 1) - 1))
DEFAULT_WAITING = 2
RESULTS_KEPT = 64  # diagnoses (JSON, tens of kB each)
REPORTS_KEPT = 8  # HTML reports (figures embedded, a few hundred kB each)
PROGRESS_STEP = 0.01  # a worker reports progress when it moved by this much (or the stage changed)

Progress = Callable[[float, str], None]


class Busy(Exception):
    """As many diagnoses as the service runs and queues are under way; try again shortly."""


class WorkerDied(Exception):
    """The worker process ended without an answer (killed, out of memory)."""


# -- what the workers run (module level, so that spawned processes can import it) ------------------
def diagnose_csv(inp: RecordingInput, max_samples: int, stages: list[dict[str, Any]] | None, full_scale_dps: float | None,
                 report_title: str | None, progress: Progress | None = None) -> tuple[dict[str, Any], str | None]:
    """Read a recording (through calib's one door, as for a calibration) and diagnose it: (Diagnosis.to_dict(), the
    HTML report or None).

    ``stages`` (Stage.to_dict() form) are used instead of detecting them, as a session accepted them;
    ``full_scale_dps`` is the gyro range the wearable stated (a CSV does not carry it).
    Raises calib's errors (RecordingError, ProtocolError, ...) and server.compute.TooManySamples.
    """
    from calib.diagnosis import diagnose
    from calib.stages.stage import Stage

    from .compute import parse_upload

    read = parse_upload(inp, max_samples)
    rec = read.recording
    if full_scale_dps:
        rec = rec.with_meta(gyro_full_scale_dps=float(full_scale_dps))
    found = [Stage.from_dict(s) for s in stages] if stages else None
    diag = diagnose(rec, progress=progress, stages=found, max_samples=max_samples, protocol=read.protocol,
                    sections=read.sections)
    html = None
    if report_title is not None:
        from calib.diagnosis.report import write_report

        with tempfile.TemporaryDirectory(prefix="gyrocal-report-") as tmp:
            html = Path(write_report(diag, tmp, title=report_title)).read_text(encoding="utf-8")
    return diag.to_dict(), html


class _Reporter:
    """A worker's progress callback: sends (fraction, stage) through the pipe when either moved."""

    def __init__(self, conn: Connection) -> None:
        self.conn = conn
        self.last = (-1.0, "")

    def __call__(self, fraction: float, stage: str) -> None:
        if fraction - self.last[0] >= PROGRESS_STEP or stage != self.last[1] or fraction >= 1.0:
            self.last = (fraction, stage)
            self.conn.send(("progress", float(fraction), str(stage)))


def _serve(conn: Connection, service_pid: int, memory_mb: int | None = None) -> None:
    """A worker's loop: (function, args) in; progress messages, then ("ok", value) or ("error", exc) out."""
    from .compute import confine_worker

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the service stops its workers itself
    confine_worker(memory_mb, service_pid)
    while True:
        try:
            fn, args = conn.recv()
        except (EOFError, OSError):
            return
        try:
            value = fn(*args, progress=_Reporter(conn))
        except Exception as exc:  # sent back to the service, which decides what the client is told
            try:
                conn.send(("error", exc))
            except Exception:  # an exception that cannot be pickled: its text is enough
                conn.send(("error", RuntimeError(f"{type(exc).__name__}: {exc}")))
            continue
        conn.send(("ok", value))


# -- one worker process ----------------------------------------------------------------------------
class Worker:
    """A spawned process that runs one call at a time; killed when a call runs over its time limit."""

    def __init__(self, memory_mb: int | None = None) -> None:
        self.memory_mb = memory_mb
        self._proc: multiprocessing.process.BaseProcess | None = None
        self._conn: Connection | None = None

    def _ensure(self) -> Connection:
        if self._proc is None or not self._proc.is_alive() or self._conn is None:
            self.stop()
            ctx = multiprocessing.get_context("spawn")
            parent, child = ctx.Pipe()
            proc = ctx.Process(target=_serve, args=(child, os.getpid(), self.memory_mb), name="gyrocal-diagnosis", daemon=True)
            proc.start()
            child.close()
            self._proc, self._conn = proc, parent
        return self._conn

    async def call(self, fn: Callable[..., Any], args: tuple[Any, ...], on_progress: Progress, timeout_s: float) -> Any:
        conn = self._ensure()
        loop = asyncio.get_running_loop()
        answer: asyncio.Future[tuple[str, Any]] = loop.create_future()

        def readable() -> None:
            try:
                while not answer.done() and conn.poll():
                    kind, *rest = conn.recv()
                    if kind == "progress":
                        on_progress(*rest)
                    else:
                        answer.set_result((kind, rest[0]))
            except (EOFError, OSError):
                if not answer.done():
                    answer.set_exception(WorkerDied("the diagnosis worker stopped without an answer"))

        fd = conn.fileno()
        loop.add_reader(fd, readable)
        try:
            await asyncio.to_thread(conn.send, (fn, args))  # a large CSV: off the event loop
            kind, value = await asyncio.wait_for(answer, timeout_s)
        except BaseException as exc:
            # timed out, cancelled or the worker died: whatever it was doing is abandoned with it
            loop.remove_reader(fd)
            self.stop()
            if isinstance(exc, (OSError, EOFError)) and not isinstance(exc, TimeoutError):  # the pipe broke
                raise WorkerDied(f"the diagnosis worker stopped without an answer ({type(exc).__name__})") from None
            raise
        loop.remove_reader(fd)
        if kind == "error":
            raise value
        return value

    def stop(self) -> None:
        if self._conn is not None:
            with contextlib.suppress(OSError):
                self._conn.close()
            self._conn = None
        if self._proc is not None:
            if self._proc.is_alive():
                self._proc.kill()
            self._proc.join(timeout=5)
            self._proc = None

    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc is not None and self._proc.is_alive() else None


# -- the queue -------------------------------------------------------------------------------------
class Lru:
    """The ``size`` most recently used values by key."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._d: OrderedDict[str, Any] = OrderedDict()

    def get(self, key: str) -> Any | None:
        if key not in self._d:
            return None
        self._d.move_to_end(key)
        return self._d[key]

    def put(self, key: str, value: Any) -> None:
        self._d[key] = value
        self._d.move_to_end(key)
        while len(self._d) > self.size:
            self._d.popitem(last=False)

    def __contains__(self, key: str) -> bool:
        return key in self._d

    def __len__(self) -> int:
        return len(self._d)


@dataclass
class Job:
    """A diagnosis under way: queued, then running with the worker's last progress report."""

    key: str
    state: Literal["queued", "running"] = "queued"
    fraction: float = 0.0
    stage: str = "waiting for a free worker"
    created: float = field(default_factory=time.monotonic)
    started: float | None = None
    task: asyncio.Task[Any] | None = None

    @property
    def elapsed_s(self) -> float:
        return time.monotonic() - self.created


Runner = Callable[[Job, Callable[..., Any], tuple[Any, ...], float], Awaitable[Any]]


class DiagnosisQueue:
    """At most ``workers`` diagnoses at once and ``max_waiting`` queued, each value kept by its key.

    ``get(key, fn, *args, into=lru)`` returns the value kept in ``lru``, joins the job already computing
    that key, or starts one (``Busy`` when the queue is full); the value is kept in ``lru`` (default:
    ``results``). Errors are not kept. ``runner`` runs one call (default: in the worker processes);
    tests pass their own.
    """

    def __init__(self, workers: int = DEFAULT_WORKERS, max_waiting: int = DEFAULT_WAITING, timeout_s: float = 120.0,
                 kept: int = RESULTS_KEPT, runner: Runner | None = None, memory_mb: int | None = None) -> None:
        self.workers = workers
        self.max_waiting = max_waiting
        self.timeout_s = timeout_s
        self.results = Lru(kept)
        self._idle: list[Worker] = [Worker(memory_mb) for _ in range(workers)] if runner is None else []
        self._all = list(self._idle)
        self._free: asyncio.Condition | None = None
        self._runner = runner or self._in_worker
        self.jobs: dict[str, Job] = {}

    async def get(self, key: str, fn: Callable[..., Any], *args: Any, into: Lru | None = None) -> tuple[Any, bool]:
        """(value, True if it was kept from before)."""
        lru = self.results if into is None else into
        hit = lru.get(key)
        if hit is not None:
            return hit, True
        job = self.jobs.get(key)
        if job is None:
            if len(self.jobs) >= self.workers + self.max_waiting:
                raise Busy(f"{len(self.jobs)} model checks are under way, as many as this service runs and queues at once; "
                           "try again in a few seconds")
            job = Job(key)
            job.task = asyncio.get_running_loop().create_task(self._run(job, fn, args, lru), name=f"diagnosis-{key[:12]}")
            # an error nobody waits for any more (every client gone) is not an unhandled one
            job.task.add_done_callback(lambda t: t.cancelled() or t.exception())
            self.jobs[key] = job
        assert job.task is not None
        # shielded: a client that goes away does not stop the diagnosis others may be waiting for
        return await asyncio.shield(job.task), False

    async def _run(self, job: Job, fn: Callable[..., Any], args: tuple[Any, ...], lru: Lru) -> Any:
        try:
            value = await self._runner(job, fn, args, self.timeout_s)
            lru.put(job.key, value)
            return value
        finally:
            self.jobs.pop(job.key, None)

    async def _in_worker(self, job: Job, fn: Callable[..., Any], args: tuple[Any, ...], timeout_s: float) -> Any:
        if self._free is None:
            self._free = asyncio.Condition()
        async with self._free:
            await self._free.wait_for(lambda: bool(self._idle))
            worker = self._idle.pop()
        job.state, job.stage, job.started = "running", "starting", time.monotonic()

        def progress(fraction: float, stage: str) -> None:
            job.fraction, job.stage = fraction, stage

        try:
            return await worker.call(fn, args, progress, timeout_s)
        finally:
            async with self._free:
                self._idle.append(worker)
                self._free.notify()

    def shutdown(self) -> None:
        for job in list(self.jobs.values()):
            if job.task is not None:
                job.task.cancel()
        for w in self._all:
            w.stop()


def digest(*parts: Any) -> str:
    """A cache key: the SHA-256 of the parts' JSON."""
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()
