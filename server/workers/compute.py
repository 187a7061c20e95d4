"""CPU-heavy work of the service in worker processes: estimators, CSV archives, parsing uploads.

Keeping it out of the service's process keeps the event loop (and so the live event streams of
every other session) responsive while a session's result is computed.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import io
import logging
import multiprocessing
import os
from collections.abc import Awaitable, Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ..live.codes import EndReason

if TYPE_CHECKING:
    from calib.io.inputs import ReadRecording, RecordingInput
    from calib.judge.verification import TurnVerification
    from calib.recording import Recording
    from calib.result import CalibrationResult
    from calib.stages.stage import Stage

log = logging.getLogger(__name__)


class TooManySamples(Exception):
    """An upload with more samples than the service accepts."""


def confine_worker(memory_mb: int | None, service_pid: int) -> None:
    """Run at a worker process's start: cap its address space at ``memory_mb`` (an allocation beyond it raises
    MemoryError instead of taking the machine's memory), and end it when the service's process (``service_pid``, which
    spawned it) is gone, even after kill -9 and even when it went while this worker was still starting, so no worker
    outlives the service."""
    import resource
    import threading

    if memory_mb:
        limit = int(memory_mb) * 1024 * 1024
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    threading.Thread(target=watch_parent, args=(service_pid,), name="gyrocal-parent-watch", daemon=True).start()


def watch_parent(service_pid: int) -> None:
    """End this process once ``service_pid``, its parent, is gone. Waits on a pidfd (no clock: a shifted or stepped
    clock cannot end the watch); where there is none, polls the parent's id, and a sleep that fails (EINVAL was seen
    under a shifted clock) is not the end of the watch, only of that sleep."""
    import select
    import time

    pidfd = None
    with contextlib.suppress(AttributeError, OSError):  # no pidfd_open (an older kernel), or the parent is gone
        pidfd = os.pidfd_open(service_pid)
    if pidfd is not None and os.getppid() == service_pid:  # the pidfd is of our parent, not of a reused id
        while True:
            with contextlib.suppress(OSError, ValueError):
                poller = select.poll()
                poller.register(pidfd, select.POLLIN)
                if poller.poll():  # readable once the process has ended
                    break
    else:
        while os.getppid() == service_pid:  # an orphan is adopted by another process: its parent id changes
            try:
                time.sleep(0.5)
            except (OSError, ValueError):
                with contextlib.suppress(OSError, ValueError):
                    select.select([], [], [], 0.5)  # a second way to wait, without the sleep that failed
    os._exit(0)


# -- what the workers run (module level, so that they can be pickled) ------------------------------
def _warm_up() -> int:
    import calib.estimators.closure.estimator  # noqa: F401
    import calib.estimators.paper  # noqa: F401
    import calib.io.readers  # noqa: F401
    import calib.pipeline  # noqa: F401

    gc.freeze()  # the numerics stay loaded for the worker's life: no full collection walks them again, nor its exit
    return os.getpid()


def recording_csv(rec: Any) -> bytes:
    """A Recording as gyrocal's native CSV (exact round trip), UTF-8."""
    from calib.io.readers import write_native_csv

    buf = io.StringIO()
    write_native_csv(rec, buf)
    return buf.getvalue().encode()


@dataclass(frozen=True)
class LiveOutcome:
    """A live session's calibration as the worker hands it back: the result, or why there is none (an exception would
    lose the recording, which the session keeps either way), and the recording as native CSV.
    ``refusal``: the whole sentence the session ends with, what happened and what to do; ``code``: the estimator's
    refusal code (calib.errors), if it refused; ``end``: why the session ends, as its ``reason_code`` says it."""

    result: CalibrationResult | None
    refusal: str | None
    code: str | None
    csv: bytes
    end: EndReason = EndReason.CALIBRATION_FAILED


def calibrate_live(rec: Recording, method: str, stages: list[Stage], heading_prior_deg: float | None = None) -> LiveOutcome:
    """A live session's recording calibrated through the one entry point (``calib.pipeline.calibrate_protocol``, the
    paper protocol, with the stages the session followed; ``heading_prior_deg``: the site's stated heading spread)."""
    from calib.errors import GyrocalError, Refusal
    from calib.pipeline import calibrate_protocol

    csv = recording_csv(rec)
    try:
        result, _ = calibrate_protocol(rec, "paper", method, stages=stages, heading_prior_deg=heading_prior_deg)
    except GyrocalError as exc:
        return LiveOutcome(None, f"{exc} Start a new calibration.", exc.code if isinstance(exc, Refusal) else None, csv)
    return LiveOutcome(result, None, None, csv)


def parse_upload(inp: RecordingInput, max_samples: int) -> ReadRecording:
    """An uploaded recording read through the one door (``calib.io.inputs.read_input``); raises RecordingError, or
    TooManySamples above ``max_samples``."""
    from calib.io.inputs import read_input

    read = read_input(inp)
    if len(read.recording) > max_samples:
        raise TooManySamples(f"the recording has {len(read.recording)} samples; at most {max_samples} are accepted, send a "
                             "shorter one")
    return read


def calibrate_upload(inp: RecordingInput, method: str, max_samples: int, heading_prior_deg: float | None = None,
                     ) -> tuple[CalibrationResult, str, bytes, int]:
    """Read and calibrate an uploaded recording: (result, protocol used, CSV, samples); raises calib's errors."""
    from calib.pipeline import calibrate_protocol

    read = parse_upload(inp, max_samples)
    result, used = calibrate_protocol(read.recording, read.protocol, method, read.sections,
                                      heading_prior_deg=heading_prior_deg)
    return result, used, recording_csv(read.recording), len(read.recording)


def off_loop(pool: ComputePool | None, fn: Callable[..., Any], *args: Any) -> Awaitable[Any]:
    """``fn(*args)`` off the event loop: in the pool's worker processes, or in a thread when there is no pool."""
    return pool.run(fn, *args) if pool is not None else asyncio.to_thread(fn, *args)


# -- the pool --------------------------------------------------------------------------------------
class ComputePool:
    """A small pool of worker processes (spawned, so safe next to the event loop's threads)."""

    def __init__(self, workers: int | None = None, memory_mb: int | None = None) -> None:
        cores = os.cpu_count() or 1
        self.workers = workers or max(1, min(4, cores - 1))
        self.memory_mb = memory_mb
        self._pool: ProcessPoolExecutor | None = None

    def _executor(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(
                self.workers, mp_context=multiprocessing.get_context("spawn"), initializer=confine_worker,
                initargs=(self.memory_mb, os.getpid())
            )
        return self._pool

    async def start(self) -> None:
        """Start the workers and import the numerics in them, so that the first result is quick."""
        loop = asyncio.get_running_loop()
        pool = self._executor()
        for _ in range(self.workers):
            loop.run_in_executor(pool, _warm_up)

    async def run(self, fn: Callable[..., Any], *args: Any) -> Any:
        loop = asyncio.get_running_loop()
        try:
            return await loop.run_in_executor(self._executor(), fn, *args)
        except BrokenProcessPool:
            # a worker died (out of memory, killed): start a fresh pool and try once more
            log.warning("the compute pool broke; restarting it")
            self._pool = None
            return await loop.run_in_executor(self._executor(), fn, *args)

    def shutdown(self) -> None:
        if self._pool is not None:
            # waiting lets the pool release its queues' semaphores (no "leaked semaphore" warning at exit);
            # the workers are idle or finishing one short job
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


def apply_upload(inp: RecordingInput, max_samples: int, calibration: dict[str, Any], orientation: bool = False,
                 temperature_model: dict[str, Any] | None = None, temperature_c: float | None = None
                 ) -> tuple[bytes, bool, float | None, dict[str, Any] | None, str | None]:
    """An uploaded CSV corrected by a calibration (its JSON form): (native CSV, whether the accelerometer was corrected
    too, the recording's mean temperature in degC when it has a temp column, with ``orientation`` the summary of
    its orientation before and after, and how the device's ``temperature_model`` was applied: "per sample" from the
    temp column, "at T degC" (``temperature_c``), or None); raises calib's errors."""
    from calib.apply.correction import Correction, corrected

    rec = parse_upload(inp, max_samples).recording
    correction = Correction.from_json(calibration)
    fixed, how = corrected(rec, correction), None
    if temperature_model is not None and (rec.temp is not None or temperature_c is not None):
        from calib.apply.temperature import TemperatureModel, corrected_at_temperature

        fixed = corrected_at_temperature(rec, correction, TemperatureModel.from_json(temperature_model), temperature_c)
        how = "per sample" if rec.temp is not None else f"at {temperature_c:g} °C"
    summary = None
    if orientation:
        from calib.apply.orientation import orientation as estimate

        summary = estimate(rec, fixed).summary()
    return recording_csv(fixed), correction.A is not None and rec.accel is not None, rec.mean_temperature_c, summary, how


def verify_recording(rec: Recording, calibration: dict[str, Any]) -> TurnVerification:
    """The verification turn of a recording measured with a calibration (its JSON form); raises NoVerificationTurn."""
    from calib.apply.correction import Correction
    from calib.judge.verification import verify_turn

    return verify_turn(rec, Correction.from_json(calibration), calibration.get("uncertainty"))


def verify_upload(inp: RecordingInput, max_samples: int, calibration: dict[str, Any]) -> tuple[TurnVerification, bytes, int]:
    """An uploaded recording of a verification turn measured with a calibration: (verification, CSV, samples)."""
    rec = parse_upload(inp, max_samples).recording
    return verify_recording(rec, calibration), recording_csv(rec), len(rec)


def noise_upload(inp: RecordingInput, max_samples: int, topic: str) -> dict[str, Any]:
    """An uploaded rest's noise (``calib.noise``) as JSON, with Kalibr's imu.yaml when it has the accelerometer."""
    from calib.exports.kalibr import kalibr_imu_yaml
    from calib.noise.analysis import noise

    report = noise(parse_upload(inp, max_samples).recording)
    return {**report.to_json(), "kalibr_yaml": None if report.accel is None else kalibr_imu_yaml(report, topic)}


def watch_upload(inp: RecordingInput, max_samples: int, calibration: dict[str, Any]) -> tuple[dict[str, Any], bytes, int]:
    """An uploaded study recording watched against a calibration: (report as JSON, CSV, samples)."""
    from calib.apply.correction import Correction
    from calib.watch import watch

    rec = parse_upload(inp, max_samples).recording
    report = watch(rec, Correction.from_json(calibration))
    return report.to_json(), recording_csv(rec), len(rec)
