"""A live verification turn: the wearable streams until it has rested, turned once all the way round about any axis
and rested again (calib.judge.verification), then the turn is measured with the calibration and kept with it
(docs/lifecycle.md, "Verified in the field"). The page follows it by polling GET /verifications/{id}."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, Field

from calib import __version__
from calib.judge.verification import find_turn

from ..devices import Device
from ..link import RecordingBuilder
from ..store import CalibrationRecord, Store, StoredVerification
from ..workers.compute import ComputePool, off_loop, recording_csv, verify_recording

log = logging.getLogger(__name__)

VerifyState = Literal["connecting", "still", "turn", "settle", "computing", "done", "failed"]

TIME_LIMIT_S = 90.0  # wall-clock seconds for the whole turn, rests included
CHECK_EVERY_S = 0.5  # device seconds of new samples between looks for the turn
MOVING_DPS = 20.0  # a reading this fast means the hand is turning (for the prompt only; the turn is found by calib)

PROMPTS = {
    "connecting": "Connecting to the wearable…",
    "still": "Hold the device still against the block.",
    "turn": "Turn it once all the way round, about any axis, back against the block.",
    "settle": "Hold it still again against the block.",
    "computing": "Measuring the turn…",
}


class VerificationRunOut(BaseModel):
    """A live verification as it runs (GET /verifications/{id})."""

    verification_id: str
    calibration_id: int
    device_id: str
    state: VerifyState
    prompt: str | None = Field(None, description="what the clinician should do now")
    reason: str | None = Field(None, description="why it failed")
    result: StoredVerification | None = Field(None, description="the verification kept, once done")


class VerifyRun:
    """One verification turn of one accepted calibration, on its device."""

    def __init__(self, run_id: str, device: Device, calibration: CalibrationRecord, store: Store, pool: ComputePool | None,
                 operator: str, on_end: Callable[[VerifyRun], None] | None = None) -> None:
        self.id = run_id
        self.device = device
        self.calibration = calibration
        self.store = store
        self.pool = pool
        self.operator = operator
        self.on_end = on_end
        self.state: VerifyState = "connecting"
        self.reason: str | None = None
        self.result: StoredVerification | None = None
        self.started = time.monotonic()
        self._task: asyncio.Task[None] | None = None
        self._moved = False

    def snapshot(self) -> VerificationRunOut:
        return VerificationRunOut(verification_id=self.id, calibration_id=self.calibration.id, device_id=self.device.id,
                                  state=self.state, prompt=PROMPTS.get(self.state), reason=self.reason, result=self.result)

    def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(self._run())

    async def wait(self) -> None:
        if self._task is not None:
            with contextlib.suppress(asyncio.CancelledError):
                await self._task

    def cancel(self) -> None:
        if self._task is not None and not self._task.done():
            self._task.cancel()

    async def _run(self) -> None:
        link = self.device.get_link()
        try:
            async with asyncio.timeout(TIME_LIMIT_S):
                rec = await self._record(link)
            self.state = "computing"
            verification = await off_loop(self.pool, verify_recording, rec, self.calibration.model_dump(mode="json"))
            csv = await asyncio.to_thread(recording_csv, rec)
            stored = await asyncio.to_thread(self.store.add_verification, self.calibration.id, self.operator, __version__,
                                             verification, source="live", recording_csv=csv, n_samples=len(rec))
            self.result, self.state = stored, "done"
        except TimeoutError:
            self._failed(f"no full turn between two rests within {TIME_LIMIT_S:g} s: start again, and turn the device once "
                         "all the way round with a still moment before and after")
        except asyncio.CancelledError:
            self._failed("cancelled")
        except Exception as exc:  # the link, the store: said in words, never a hanging run
            log.warning("verification %s failed: %s", self.id, exc, exc_info=True)
            self._failed(f"the verification could not be completed ({exc}); start it again")
        finally:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(link.stop(), timeout=5.0)
            if self.on_end is not None:
                self.on_end(self)

    def _failed(self, reason: str) -> None:
        self.state, self.reason = "failed", reason

    async def _record(self, link: Any) -> Any:
        """Stream until the recording holds a rest, a full turn and a rest; the recording so far."""
        if not getattr(link, "connected", False):
            await link.connect()
        info = await link.read_info()
        builder = RecordingBuilder(info, source=f"verification of calibration #{self.calibration.id}")
        await link.start()
        self.state = "still"
        looked_at = 0.0
        async for item in link.samples():
            if getattr(item, "kind", None) is not None:
                if item.kind in ("link_failed", "stream_ended"):
                    raise RuntimeError("the link to the wearable was lost")
                continue
            builder.add(item)
            t_end = float(item.t_device_s[-1]) if len(item.t_device_s) else looked_at
            if t_end - looked_at < CHECK_EVERY_S:
                continue
            looked_at = t_end
            rec = builder.recording()
            if find_turn(rec) is not None:
                return rec
            moving = len(rec) >= 5 and float(np.abs(rec.gyro[-5:]).max()) > MOVING_DPS
            if self.state == "still" and rec.t[-1] - rec.t[0] >= 2.0:
                self.state = "turn"
            elif self.state == "turn" and moving:
                self._moved = True
            elif self.state == "turn" and self._moved and not moving:
                self.state = "settle"
        raise RuntimeError("the wearable stopped streaming")
