"""A calibration at work outside the service: POST /devices/{id}/apply (a recording corrected: CSV in, CSV out),
GET /calibrations/{id}?format= (a calibration written for other tools) and POST /devices/{id}/calibrations (one
made elsewhere imported into the history)."""

from __future__ import annotations

import asyncio
import json
from dataclasses import replace
from datetime import datetime
from typing import Annotated, Any

from fastapi import APIRouter, Path, Query, Request, Response

from calib import __version__
from calib.apply.correction import Correction, CorrectionFileError
from calib.apply.identity import SensorIdentity
from calib.errors import GyrocalError
from calib.io.inputs import ReadOptions
from calib.json_safe import finite

from ... import schemas as M
from ...deps import R404, R409, Operator, Reader, Svc, check_device_id, check_upload, problem, read_csv_body
from ...export import export_text
from ...lifecycle import CalibrationInForce, in_force_async, judged, none_in_force, temperature_model
from ...service import Service
from ...store import sha256_hex
from ...workers.compute import apply_upload
from ..identity_query import RecordingIdentity
from ..upload_options import Upload, upload_input
from ..upload_work import upload_work
from ..views import calibration_or_404

router = APIRouter()


@router.post(
    "/devices/{device_id}/apply",
    response_class=Response,
    responses={
        200: {"content": {"text/csv": {}}, "description": "the recording corrected (native CSV); X-Gyrocal-Calibration-Id "
              "names the calibration used, X-Gyrocal-Calibration its parameters (JSON), X-Gyrocal-Warnings its warnings (JSON list), "
              "X-Gyrocal-Identity-Check the sensor, power-up and temperature compared (JSON), X-Gyrocal-Temperature-Model the "
              "device's k and b against temperature its watches measured and how it was applied (per sample, at one "
              "temperature, or not: applied null) or null when its watches measured none (JSON)"},
        400: {"model": M.Problem, "description": "the recording cannot be read"},
        413: {"model": M.Problem, "description": "the recording is too large"},
        415: {"model": M.Problem, "description": "not a CSV body"},
        **R404, **R409,
    },
    openapi_extra={"requestBody": {"required": True, "content": {"text/csv": {"schema": {"type": "string"}}}}},
    tags=["calibrations"],
)
async def apply_calibration(
    svc: Svc, device_id: str, request: Request, _: Reader, upload: Upload, recording: RecordingIdentity,
    at: Annotated[datetime | None, Query(description="when the recording was made (ISO 8601); default now")] = None,
    fs: Annotated[float | None, Query(gt=0, le=100000, description="sample rate, Hz (CSV without a time column)")] = None,
    layout: Annotated[str, Query(max_length=16, description="CSV layout: auto, native, imucal")] = "auto",
) -> Response:
    """Correct an uploaded recording with the device's calibration in force for it (as GET /devices/{id}/calibration
    chooses it: same power-up first, never another sensor's) on the gyroscope, and on the accelerometer too when that
    calibration has its model. Nothing is stored."""
    cal, (csv, accel_too, _, temperature) = await _corrected(svc, device_id, request, upload, recording, at, fs, layout,
                                                             orientation=False)
    params = cal.model_dump(mode="json")
    used = {k: params[k] for k in ("k", "b", "K", "G")}
    return Response(csv, media_type="text/csv", headers={
        "X-Gyrocal-Calibration-Id": str(cal.id),
        "X-Gyrocal-Calibration": json.dumps(used, separators=(",", ":")),
        "X-Gyrocal-Corrected": "gyroscope,accelerometer" if accel_too else "gyroscope",
        "X-Gyrocal-Warnings": json.dumps(cal.in_force.warnings),
        "X-Gyrocal-Identity-Check": json.dumps(cal.in_force.identity_check, separators=(",", ":")),
        "X-Gyrocal-Temperature-Model": json.dumps(temperature, separators=(",", ":")),
        "Content-Disposition": f'attachment; filename="{device_id}-calibrated.csv"',
    })


async def _corrected(svc: Service, device_id: str, request: Request, upload: ReadOptions, recording: SensorIdentity,
                     at: datetime | None, fs: float | None, layout: str, *, orientation: bool) -> tuple[CalibrationInForce, Any]:
    """The calibration in force for an uploaded recording (judged against the recording's temp column too) and what the
    worker made of the recording with it: (corrected CSV, accelerometer corrected too, orientation summary or None)."""
    check_device_id(device_id)
    body = await read_csv_body(request)
    check_upload(body, layout)
    cal = await in_force_async(svc.store, device_id, at, svc.settings.limits, recording)
    if cal is None:
        raise problem(404, f"{none_in_force(device_id, None if at is None else at.isoformat())}: calibrate it before applying one")
    model = await asyncio.to_thread(temperature_model, svc.store, cal)
    csv, accel_too, temperature_c, summary, how = await upload_work(
        svc, apply_upload, upload_input(body, f"recording for {device_id}", upload, fs, layout), svc.settings.max_upload_samples,
        cal.model_dump(mode="json"), orientation, None if model is None else model.to_json(), recording.temperature_c,
        doing="corrected",
        too_slow=f"correcting this recording took longer than {svc.settings.compute_timeout_s:g} s; try again later")
    if recording.temperature_c is None and temperature_c is not None:  # the recording's temp column: judged against it
        cal = judged(cal, cal.in_force.at, svc.settings.limits, replace(recording, device_id=device_id, temperature_c=temperature_c),
                     cal.in_force.chosen_by)
    temperature = None if model is None else {**model.to_json(), "applied": how}
    return cal, (csv, accel_too, summary, temperature)


@router.post(
    "/devices/{device_id}/orientation",
    responses={
        200: {"model": M.OrientationOut, "description": "t (s), roll/pitch/yaw before and after correction (deg, unwrapped), "
              "difference_deg between the two orientations, at most max_points samples; the calibration used, its warnings "
              "and identity check"},
        400: {"model": M.Problem, "description": "the recording cannot be read"},
        413: {"model": M.Problem, "description": "the recording is too large"},
        415: {"model": M.Problem, "description": "not a CSV body"},
        **R404, **R409,
    },
    openapi_extra={"requestBody": {"required": True, "content": {"text/csv": {"schema": {"type": "string"}}}}},
    tags=["calibrations"],
)
async def orientation_of(
    svc: Svc, device_id: str, request: Request, _: Reader, upload: Upload, recording: RecordingIdentity,
    at: Annotated[datetime | None, Query(description="when the recording was made (ISO 8601); default now")] = None,
    fs: Annotated[float | None, Query(gt=0, le=100000, description="sample rate, Hz (CSV without a time column)")] = None,
    layout: Annotated[str, Query(max_length=16, description="CSV layout: auto, native, imucal")] = "auto",
) -> M.OrientationOut:
    """The orientation an uploaded recording implies before and after the device's calibration in force for it
    (Madgwick's filter of the ahrs package; gyroscope integration without an accelerometer): the paper's Figs. 2 and 10
    for the user's own data. Nothing is stored."""
    cal, (_, _, summary, _) = await _corrected(svc, device_id, request, upload, recording, at, fs, layout, orientation=True)
    return M.OrientationOut.model_validate(finite({"calibration_id": cal.id, "warnings": cal.in_force.warnings,
                                                   "identity_check": cal.in_force.identity_check, **summary}))


EXPORT_FORMATS = ("gyrocal", "imucal", "openvins", "csv")


@router.get(
    "/calibrations/{calibration_id}",
    response_class=Response,
    responses={200: {"model": M.CalibrationRecord, "content": {"application/json": {}, "text/csv": {}},
                     "description": "gyrocal: the stored calibration (JSON); imucal: a Ferraris calibration file imucal's "
                     "load_calibration_info loads; openvins: OpenVINS's kalibr_imu_chain.yaml with the intrinsics (Tw, "
                     "R_IMUtoGYRO, Ta, R_IMUtoACC, Tg); csv: one row per parameter"},
               422: {"model": M.Problem, "description": "an unknown format, or a calibration that format cannot hold"}, **R404},
    tags=["calibrations"],
)
async def export_calibration(
    svc: Svc, calibration_id: Annotated[int, Path(ge=1, le=2**31 - 1)], _: Reader,
    format: Annotated[str, Query(max_length=16, description="gyrocal (default), imucal, openvins or csv")] = "gyrocal",
) -> Response:
    """One accepted calibration, for other tools: gyrocal's JSON, imucal's calibration file, OpenVINS's IMU intrinsics,
    or CSV."""
    if format not in EXPORT_FORMATS:
        raise problem(422, f"unknown format {format!r}: choose {', '.join(EXPORT_FORMATS)}")
    cal = await calibration_or_404(svc, calibration_id)
    try:
        body, media, ext = export_text(cal, format)
    except GyrocalError as exc:
        raise problem(422, f"calibration #{cal.id} cannot be written for {format}: {exc}") from None
    return Response(body, media_type=media, headers={
        "Content-Disposition": f'attachment; filename="{cal.device_id}-calibration-{cal.id}{ext}"'})


@router.post(
    "/devices/{device_id}/calibrations",
    status_code=201,
    response_model=M.AcceptOut,
    responses={400: {"model": M.Problem, "description": "the body is not JSON"}, 401: {"model": M.Problem}, **R404,
               409: {"model": M.Problem, "description": "this file was imported for the device already"},
               415: {"model": M.Problem, "description": "not a JSON body"},
               422: {"model": M.Problem, "description": "not a calibration gyrocal can use (the reason is given)"}},
    openapi_extra={"requestBody": {"required": True, "content": {"application/json": {"schema": {
        "type": "object",
        "description": "imucal's Ferraris calibration file, or gyrocal's calibration JSON ({\"k\": [..], \"b\": [..]} at least)"}}}}},
    tags=["calibrations"],
)
async def import_calibration(
    svc: Svc, device_id: str, request: Request, operator: Operator, sensor: RecordingIdentity,
    name: Annotated[str | None, Query(min_length=1, max_length=200, pattern=M.SENSOR_TEXT,
                                      description="the file's name, kept with the import")] = None,
) -> M.AcceptOut:
    """Add a calibration made elsewhere to the device's history, marked ``import``: it is in force from now. The query's
    serial, sensor_model, boot_count and temperature_c fill what the file does not say about its sensor."""
    check_device_id(device_id)
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype != "application/json":
        raise problem(415, f"send the calibration file as application/json; got {ctype or 'no content type'}")
    raw = await request.body()
    try:
        doc = json.loads(raw)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise problem(400, f"the body is not JSON ({exc}); send imucal's or gyrocal's calibration file") from None
    try:
        correction = Correction.from_json(doc)
    except CorrectionFileError as exc:
        raise problem(422, str(exc)) from None
    correction = replace(correction, identity=(correction.identity or SensorIdentity()).completed(sensor))
    await asyncio.to_thread(svc.store.upsert_device, device_id)
    rec = await asyncio.to_thread(svc.store.import_calibration, device_id, correction, operator, __version__,
                                  file_name=name or "upload.json", file_sha256=sha256_hex(raw))
    svc.events.fleet_changed("calibration", device_id)
    return M.AcceptOut(session_id=rec.session_id, calibration=rec)
