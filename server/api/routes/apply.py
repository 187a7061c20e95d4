"""A calibration at work outside the service: POST /devices/{id}/apply (a recording corrected: CSV in, CSV out) and
GET /calibrations/{id}?format= (a calibration written for other tools)."""

from __future__ import annotations

import asyncio
import json
from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, Path, Query, Request, Response

from ... import schemas as M
from ...deps import R404, Reader, Svc, check_device_id, check_upload, problem, read_csv_body, recording_problem
from ...export import export_text
from ...lifecycle import in_force_async, none_in_force
from ...workers.compute import TooManySamples, apply_upload
from ..upload_options import Upload

router = APIRouter()


@router.post(
    "/devices/{device_id}/apply",
    response_class=Response,
    responses={
        200: {"content": {"text/csv": {}}, "description": "the recording corrected (native CSV); X-Gyrocal-Calibration-Id "
              "names the calibration used, X-Gyrocal-Calibration its parameters (JSON), X-Gyrocal-Warnings its warnings (JSON list)"},
        400: {"model": M.Problem, "description": "the recording cannot be read"},
        413: {"model": M.Problem, "description": "the recording is too large"},
        415: {"model": M.Problem, "description": "not a CSV body"},
        **R404,
    },
    openapi_extra={"requestBody": {"required": True, "content": {"text/csv": {"schema": {"type": "string"}}}}},
    tags=["calibrations"],
)
async def apply_calibration(
    svc: Svc, device_id: str, request: Request, _: Reader, upload: Upload,
    at: Annotated[datetime | None, Query(description="when the recording was made (ISO 8601); default now")] = None,
    fs: Annotated[float | None, Query(gt=0, le=100000, description="sample rate, Hz (CSV without a time column)")] = None,
    layout: Annotated[str, Query(max_length=16, description="CSV layout: auto, native, imucal")] = "auto",
) -> Response:
    """Correct an uploaded recording with the device's calibration in force at ``at`` (the gyroscope; the accelerometer
    too when that calibration has its model). Nothing is stored."""
    check_device_id(device_id)
    body = await read_csv_body(request)
    check_upload(body, layout)
    cal = await in_force_async(svc.store, device_id, at, svc.settings.calibration_max_age_days)
    if cal is None:
        raise problem(404, f"{none_in_force(device_id, None if at is None else at.isoformat())}: calibrate it before applying one")
    params = cal.model_dump(mode="json")
    try:
        csv, accel_too = await asyncio.wait_for(
            svc.pool.run(apply_upload, body, fs, layout, f"recording for {device_id}", svc.settings.max_upload_samples, upload, params),
            timeout=svc.settings.compute_timeout_s,
        )
    except TimeoutError:
        raise problem(503, f"correcting this recording took longer than {svc.settings.compute_timeout_s:g} s; try again later") from None
    except TooManySamples as exc:
        raise problem(413, str(exc)) from None
    except Exception as exc:  # calib's errors and whatever else the parser trips on
        raise recording_problem(exc, "corrected", upload=True) from None
    used = {k: params[k] for k in ("k", "b", "K", "G")}
    return Response(csv, media_type="text/csv", headers={
        "X-Gyrocal-Calibration-Id": str(cal.id),
        "X-Gyrocal-Calibration": json.dumps(used, separators=(",", ":")),
        "X-Gyrocal-Corrected": "gyroscope,accelerometer" if accel_too else "gyroscope",
        "X-Gyrocal-Warnings": json.dumps(cal.in_force.warnings),
        "Content-Disposition": f'attachment; filename="{device_id}-calibrated.csv"',
    })


EXPORT_FORMATS = ("gyrocal", "imucal", "csv")


@router.get(
    "/calibrations/{calibration_id}",
    response_class=Response,
    responses={200: {"content": {"application/json": {}, "text/csv": {}},
                     "description": "gyrocal: the stored calibration (JSON); imucal: a Ferraris calibration file imucal's "
                     "load_calibration_info loads; csv: one row per parameter"}, **R404},
    tags=["calibrations"],
)
async def export_calibration(
    svc: Svc, calibration_id: Annotated[int, Path(ge=1, le=2**31 - 1)], _: Reader,
    format: Annotated[str, Query(max_length=16, description="gyrocal (default), imucal or csv")] = "gyrocal",
) -> Response:
    """One accepted calibration, for other tools: gyrocal's JSON, imucal's calibration file, or CSV."""
    if format not in EXPORT_FORMATS:
        raise problem(422, f"unknown format {format!r}: choose {', '.join(EXPORT_FORMATS)}")
    cal = await asyncio.to_thread(svc.store.calibration, calibration_id)
    if cal is None:
        raise problem(404, f"no calibration #{calibration_id}; see GET /devices/{{id}}/calibrations")
    body, media, ext = export_text(cal, format)
    return Response(body, media_type=media, headers={
        "Content-Disposition": f'attachment; filename="{cal.device_id}-calibration-{cal.id}{ext}"'})
