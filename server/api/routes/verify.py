"""Verification turns of accepted calibrations: POST /calibrations/{id}/verify (live on the device, or an uploaded
recording), GET /verifications/{id} (a live one as it runs), and the verifications kept with a calibration or a
device (docs/lifecycle.md, "Verified in the field")."""

from __future__ import annotations

import asyncio
import uuid
from typing import Annotated

from fastapi import APIRouter, Path, Query, Request, Response

from calib import __version__
from calib.judge.verification import NoVerificationTurn

from ... import schemas as M
from ...deps import CSV_TYPES, R404, R409, Operator, Reader, Svc, check_device_id, check_upload, problem
from ...live.verify_run import VerificationRunOut, VerifyRun
from ...store import StoredVerification
from ...workers.compute import verify_upload
from ..upload_options import Upload, upload_input
from ..upload_work import upload_work
from ..views import calibration_or_404, claim_device, reachable_device

router = APIRouter()
CalibrationId = Annotated[int, Path(ge=1, le=2**31 - 1)]


@router.post(
    "/calibrations/{calibration_id}/verify",
    status_code=201,
    responses={201: {"model": StoredVerification, "description": "an uploaded recording's verification turn, measured and kept"},
               202: {"model": VerificationRunOut,
                     "description": "a live verification started on the device: follow it at GET /verifications/{id}"},
               400: {"model": M.Problem, "description": "the recording cannot be read, or holds no full turn between rests"},
               401: {"model": M.Problem}, 413: {"model": M.Problem, "description": "the recording is too large"},
               415: {"model": M.Problem, "description": "neither a CSV recording nor JSON"},
               503: {"model": M.Problem, "description": "measuring took too long"}, **R404, **R409},
    openapi_extra={"requestBody": {"required": False, "content": {
        "text/csv": {"schema": {"type": "string", "description": "a recording of the verification turn"}},
        "application/json": {"schema": {"type": "object", "description": "{} (or no body): a live turn on the device"}}}}},
    tags=["calibrations"],
)
async def verify(
    svc: Svc, calibration_id: CalibrationId, request: Request, response: Response, operator: Operator, upload: Upload,
    fs: Annotated[float | None, Query(gt=0, le=100000, description="sample rate, Hz (CSV without a time column)")] = None,
    layout: Annotated[str, Query(max_length=16, description="CSV layout: auto, native, imucal")] = "auto",
) -> StoredVerification | VerificationRunOut:
    """One more full turn, about any axis, measured with the calibration: the calibrated angle (360° ± its uncertainty
    when the calibration holds) against the raw one, kept with the calibration."""
    cal = await calibration_or_404(svc, calibration_id)
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    body = await request.body()
    if ctype in CSV_TYPES:
        check_upload(body, layout)
        found, csv, n = await upload_work(
            svc, verify_upload, upload_input(body, f"verification of #{calibration_id}", upload, fs, layout),
            svc.settings.max_upload_samples, cal.model_dump(mode="json"), doing="verified",
            too_slow="measuring the turn took too long; try again later", refused=(NoVerificationTurn,))
        return await asyncio.to_thread(svc.store.add_verification, calibration_id, operator, __version__, found, source="upload",
                                       recording_csv=csv, n_samples=n)
    if ctype and ctype != "application/json" and body:
        raise problem(415, f"send a recording (text/csv) of the turn, or {{}} (application/json) for a live turn; got {ctype}")
    dev = await reachable_device(svc, cal.device_id)
    run_id = uuid.uuid4().hex
    await claim_device(svc, cal.device_id, run_id, "verify when that is done")
    run = VerifyRun(run_id, dev, cal, svc.store, svc.pool, operator, on_end=svc.verification_ended)
    svc.verify_runs[run.id] = run
    run.start()
    response.status_code = 202
    response.headers["Location"] = f"/verifications/{run.id}"
    return run.snapshot()


@router.get("/verifications/{verification_id}", response_model=VerificationRunOut, responses=R404, tags=["calibrations"])
async def verification(svc: Svc, verification_id: Annotated[str, Path(pattern=r"^[0-9a-f]{32}$")], _: Reader) -> VerificationRunOut:
    """A live verification as it runs: state (connecting, still, turn, settle, computing, done, failed), the prompt for
    the clinician, and once done the verification kept."""
    run = svc.verify_runs.get(verification_id)
    if run is None:
        raise problem(404, f"no live verification {verification_id} (finished ones are under GET /calibrations/{{id}}/verifications)")
    return run.snapshot()


@router.get("/calibrations/{calibration_id}/verifications", response_model=list[StoredVerification], responses=R404,
            tags=["calibrations"])
async def calibration_verifications(svc: Svc, calibration_id: CalibrationId, _: Reader) -> list[StoredVerification]:
    """The verification turns kept with a calibration, newest first."""
    cal = await calibration_or_404(svc, calibration_id)
    return await asyncio.to_thread(svc.store.verifications, cal.device_id, calibration_id)


@router.get("/devices/{device_id}/verifications", response_model=list[StoredVerification], responses=R404, tags=["calibrations"])
async def device_verifications(svc: Svc, device_id: str, _: Reader) -> list[StoredVerification]:
    """The verification turns of all of a device's calibrations, newest first."""
    check_device_id(device_id)
    return await asyncio.to_thread(svc.store.verifications, device_id)

