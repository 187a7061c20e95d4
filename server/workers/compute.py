"""CPU-heavy work of the service in worker processes: estimators, CSV archives, parsing uploads.

Keeping it out of the service's process keeps the event loop (and so the live event streams of
every other session) responsive while a session's result is computed.
"""

from __future__ import annotations

import asyncio
import io
import logging
import multiprocessing
import os
from collections.abc import Awaitable, Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from calib.io.section import Section
    from calib.recording import Recording
    from calib.result import CalibrationResult

log = logging.getLogger(__name__)


class TooManySamples(Exception):
    """An upload with more samples than the service accepts."""


def confine_worker(memory_mb: int | None) -> None:
    """Run at a worker process's start: cap its address space at ``memory_mb`` (an allocation beyond it raises
    MemoryError instead of taking the machine's memory), and end it when the service's process is gone (even
    after kill -9), so no worker outlives the service."""
    import resource
    import threading
    import time

    if memory_mb:
        limit = int(memory_mb) * 1024 * 1024
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    parent = os.getppid()

    def watch() -> None:
        while True:
            time.sleep(0.5)
            if os.getppid() != parent:
                os._exit(0)

    threading.Thread(target=watch, name="gyrocal-parent-watch", daemon=True).start()


# -- what the workers run (module level, so that they can be pickled) ------------------------------
def _warm_up() -> int:
    import calib.estimators.closure.estimator  # noqa: F401
    import calib.estimators.paper  # noqa: F401
    import calib.io.readers  # noqa: F401
    import calib.pipeline  # noqa: F401

    return os.getpid()


def recording_csv(rec: Any) -> bytes:
    """A Recording as gyrocal's native CSV (exact round trip), UTF-8."""
    from calib.io.readers import write_native_csv

    buf = io.StringIO()
    write_native_csv(rec, buf)
    return buf.getvalue().encode()


def calibrate_recording(rec: Recording, method: str, stages: Any) -> tuple[CalibrationResult | None, str | None, bytes]:
    """(result, None, csv) or (None, error message, csv) for a session's recording."""
    from calib.errors import GyrocalError
    from calib.pipeline import calibrate

    csv = recording_csv(rec)
    try:
        return calibrate(rec, method=method, stages=stages), None, csv
    except GyrocalError as exc:
        return None, str(exc), csv


@dataclass(frozen=True)
class UploadOptions:
    """How to read and calibrate an uploaded CSV beyond its layout: the protocol, labelled sections (imucal's
    section-list JSON text), for raw counts the sensitivities, and for imu_tk's layout its accelerometer file (the
    upload's body then being its gyroscope file)."""

    protocol: str = "auto"
    sections: str | None = None
    gyro_counts_per_dps: float | None = None
    accel_counts_per_g: float | None = None
    accel_file: bytes | None = None


def parse_upload(body: bytes, fs: float | None, layout: str, source: str, max_samples: int,
                 options: UploadOptions | None = None) -> Recording:
    """An uploaded CSV (or imu_tk's two files) as a Recording; raises RecordingError, or TooManySamples above
    ``max_samples``."""
    from calib.io.readers import parse_recording_text

    opts = options or UploadOptions()
    if layout == "imu_tk":
        rec = _parse_imu_tk_upload(body, source, opts)
    else:
        if opts.gyro_counts_per_dps is not None or opts.accel_counts_per_g is not None:
            layout = "imucal_counts" if layout in ("auto", "imucal") else layout
        rec = parse_recording_text(body, fs, layout, source, gyro_counts_per_dps=opts.gyro_counts_per_dps,
                                   accel_counts_per_g=opts.accel_counts_per_g)
    if len(rec) > max_samples:
        raise TooManySamples(f"the recording has {len(rec)} samples; at most {max_samples} are accepted, send a shorter one")
    return rec


def _parse_imu_tk_upload(gyro: bytes, source: str, opts: UploadOptions) -> Recording:
    """imu_tk's gyroscope and accelerometer files, with the sensitivities given (else the Xsens test data's)."""
    from calib.errors import RecordingError
    from calib.io.imu_tk import XSENS_ACCEL_COUNTS_PER_G, XSENS_GYRO_COUNTS_PER_RAD_S, parse_imu_tk
    from calib.units import DEG

    if opts.accel_file is None:
        raise RecordingError("imu_tk's layout is two files: send the gyroscope's and the accelerometer's as the parts "
                             "'gyro' and 'accel' of a multipart/form-data body")
    counts_per_rad_s = XSENS_GYRO_COUNTS_PER_RAD_S if opts.gyro_counts_per_dps is None else opts.gyro_counts_per_dps / DEG
    return parse_imu_tk(_text(gyro, "gyroscope"), _text(opts.accel_file, "accelerometer"), source, counts_per_rad_s,
                        opts.accel_counts_per_g or XSENS_ACCEL_COUNTS_PER_G)


def _text(data: bytes, what: str) -> str:
    from calib.errors import RecordingError

    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise RecordingError(f"the {what} file is not text: imu_tk's files are rows 't x y z' of numbers") from None


def upload_sections(opts: UploadOptions, rec: Recording) -> tuple[Section, ...] | None:
    """The upload's labelled sections (its ``sections`` parameter), checked against the recording; None without."""
    from calib.io.sections import parse_sections

    return parse_sections(opts.sections, len(rec), "the sections parameter") if opts.sections else None


def calibrate_upload(
    body: bytes, fs: float | None, layout: str, method: str, source: str, max_samples: int, options: UploadOptions | None = None
) -> tuple[CalibrationResult, str, bytes, int]:
    """Parse and calibrate an uploaded CSV: (result, protocol used, CSV, samples); raises calib's errors."""
    from calib.pipeline import calibrate_protocol

    opts = options or UploadOptions()
    rec = parse_upload(body, fs, layout, source, max_samples, opts)
    result, used = calibrate_protocol(rec, opts.protocol, method, upload_sections(opts, rec))
    return result, used, recording_csv(rec), len(rec)


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
                self.workers, mp_context=multiprocessing.get_context("spawn"), initializer=confine_worker, initargs=(self.memory_mb,)
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


def apply_upload(body: bytes, fs: float | None, layout: str, source: str, max_samples: int, options: UploadOptions | None,
                 calibration: dict[str, Any], orientation: bool = False) -> tuple[bytes, bool, float | None, dict[str, Any] | None]:
    """An uploaded CSV corrected by a calibration (its JSON form): (native CSV, whether the accelerometer was corrected
    too, the recording's mean temperature in degC when it has a temp column, and with ``orientation`` the summary of
    its orientation before and after); raises calib's errors."""
    from calib.apply.correction import Correction, corrected

    rec = parse_upload(body, fs, layout, source, max_samples, options)
    correction = Correction.from_json(calibration)
    fixed = corrected(rec, correction)
    summary = None
    if orientation:
        from calib.apply.orientation import orientation as estimate

        summary = estimate(rec, fixed).summary()
    return recording_csv(fixed), correction.A is not None and rec.accel is not None, rec.mean_temperature_c, summary


def verify_recording(rec: Any, calibration: dict[str, Any]) -> dict[str, Any]:
    """The verification turn of a recording measured with a calibration (its JSON form); raises NoVerificationTurn."""
    from calib.apply.correction import Correction
    from calib.judge.verification import verify_turn

    return verify_turn(rec, Correction.from_json(calibration), calibration.get("uncertainty")).to_json()


def verify_upload(body: bytes, fs: float | None, layout: str, source: str, max_samples: int, options: UploadOptions | None,
                  calibration: dict[str, Any]) -> tuple[dict[str, Any], bytes, int]:
    """An uploaded recording of a verification turn measured with a calibration: (verification, CSV, samples)."""
    rec = parse_upload(body, fs, layout, source, max_samples, options)
    return verify_recording(rec, calibration), recording_csv(rec), len(rec)
