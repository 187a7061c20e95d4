"""Watches of accepted calibrations on study recordings: POST /calibrations/{id}/watch (an uploaded recording made
with it in force), and the watches kept with a calibration or a device (docs/lifecycle.md, "Is the calibration still
true?")."""

from __future__ import annotations

import asyncio
from typing import Annotated

from fastapi import APIRouter, Path, Query, Request

from calib import __version__
from calib.watch.schema import TemperatureModelOut

from ... import schemas as M
from ...deps import CSV_TYPES, R404, Operator, Reader, Svc, check_device_id, check_upload, problem
from ...lifecycle import model_of
from ...store import StoredWatch
from ...workers.compute import watch_upload
from ..upload_options import Upload, upload_input
from ..upload_work import upload_work
from ..views import calibration_or_404

router = APIRouter()
CalibrationId = Annotated[int, Path(ge=1, le=2**31 - 1)]


@router.post(
    "/calibrations/{calibration_id}/watch",
    status_code=201,
    response_model=StoredWatch,
    responses={201: {"description": "the recording's verdict on each parameter of the calibration, kept with it"},
               400: {"model": M.Problem, "description": "the recording cannot be read, or has too few rests to tell anything"},
               401: {"model": M.Problem}, 413: {"model": M.Problem, "description": "the recording is too large"},
               415: {"model": M.Problem, "description": "not a CSV recording"},
               503: {"model": M.Problem, "description": "watching took too long"}, **R404},
    openapi_extra={"requestBody": {"required": True, "content": {
        "text/csv": {"schema": {"type": "string", "description": "a study recording made with the calibration in force"}}}}},
    tags=["calibrations"],
)
async def watch_calibration(
    svc: Svc, calibration_id: CalibrationId, request: Request, operator: Operator, upload: Upload,
    fs: Annotated[float | None, Query(gt=0, le=100000, description="sample rate, Hz (CSV without a time column)")] = None,
    layout: Annotated[str, Query(max_length=16, description="CSV layout: auto, native, imucal")] = "auto",
    name: Annotated[str | None, Query(max_length=200, description="the recording's name, kept with the watch")] = None,
) -> StoredWatch:
    """Whether the calibration still holds on a study recording made with it in force: its rests test each bias, its
    re-orientations between rests each scale factor, against the temperature column when there is one. Each of k_x..b_z
    holds, moved (by how much, since when) or cannot tell (and which motion would tell); kept with the calibration."""
    cal = await calibration_or_404(svc, calibration_id)
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype not in CSV_TYPES:
        raise problem(415, f"send the study recording as text/csv; got {ctype or 'no content type'}")
    body = await request.body()
    check_upload(body, layout)
    report, csv, n = await upload_work(
        svc, watch_upload, upload_input(body, f"watch of #{calibration_id}", upload, fs, layout), svc.settings.max_upload_samples,
        cal.model_dump(mode="json"), doing="watched", too_slow="watching the recording took too long; try again later")
    return await asyncio.to_thread(svc.store.add_watch, calibration_id, operator, __version__, report, recording_name=name,
                                   recording_csv=csv, n_samples=n)


@router.get("/calibrations/{calibration_id}/watches", response_model=list[StoredWatch], responses=R404, tags=["calibrations"])
async def calibration_watches(svc: Svc, calibration_id: CalibrationId, _: Reader) -> list[StoredWatch]:
    """The watches kept with a calibration, newest first."""
    cal = await calibration_or_404(svc, calibration_id)
    return await asyncio.to_thread(svc.store.watches, cal.device_id, calibration_id)


@router.get("/devices/{device_id}/watches", response_model=list[StoredWatch], responses=R404, tags=["calibrations"])
async def device_watches(svc: Svc, device_id: str, _: Reader) -> list[StoredWatch]:
    """The watches of all of a device's calibrations, newest first."""
    check_device_id(device_id)
    return await asyncio.to_thread(svc.store.watches, device_id)


@router.get("/devices/{device_id}/temperature-model", response_model=TemperatureModelOut | None, responses=R404,
            tags=["calibrations"])
async def device_temperature_model(svc: Svc, device_id: str, _: Reader) -> TemperatureModelOut | None:
    """The device's k and b against its temperature, as its watches measured them about its current calibration's
    temperature (what POST /devices/{id}/apply corrects with); null when no watch had a temperature column or the
    calibration does not say its temperature."""
    check_device_id(device_id)
    cal = await asyncio.to_thread(svc.store.current_calibration, device_id)
    if cal is None:
        raise problem(404, f"{device_id!r} has no accepted calibration; see GET /devices")
    watches = await asyncio.to_thread(svc.store.watches, device_id)
    cals = await asyncio.to_thread(svc.store.calibrations, device_id)
    model = model_of(cal, watches, cals)
    if model is None:
        return None
    seen = [t for w in watches if w.temperature_c for t in w.temperature_c] + [
        c.identity.temperature_c for c in cals if c.identity is not None and c.identity.temperature_c is not None]
    seen = seen or [model.temp_ref_c]
    return TemperatureModelOut.model_validate({**model.to_json(), "calibration_id": cal.id, "watched_c": [min(seen), max(seen)]})
