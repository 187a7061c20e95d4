"""Noise from a long rest: POST /noise (an uploaded recording of the device lying still; nothing is stored)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Request

from calib.errors import Refusal
from calib.noise.schema import NoiseOut

from ... import schemas as M
from ...deps import CSV_TYPES, Operator, Svc, check_upload, problem
from ...workers.compute import noise_upload
from ..upload_options import Upload, upload_input
from ..upload_work import upload_work

router = APIRouter()


@router.post(
    "/noise",
    response_model=NoiseOut,
    responses={400: {"model": M.Problem, "description": "the recording cannot be read, moves, or is too short a rest"},
               401: {"model": M.Problem}, 413: {"model": M.Problem, "description": "the recording is too large"},
               415: {"model": M.Problem, "description": "not a CSV recording"},
               503: {"model": M.Problem, "description": "the analysis took too long"}},
    openapi_extra={"requestBody": {"required": True, "content": {
        "text/csv": {"schema": {"type": "string", "description": "a recording of the device lying still"}}}}},
    tags=["noise"],
)
async def rest_noise(
    svc: Svc, request: Request, _: Operator, upload: Upload,
    fs: Annotated[float | None, Query(gt=0, le=100000, description="sample rate, Hz (CSV without a time column)")] = None,
    layout: Annotated[str, Query(max_length=16, description="CSV layout: auto, native, imucal")] = "auto",
    name: Annotated[str | None, Query(max_length=200, description="the recording's name, in the report")] = None,
    topic: Annotated[str, Query(max_length=200, pattern=r"^/[A-Za-z0-9_/]*$", description="the IMU's ROS topic in Kalibr's "
                                "imu.yaml")] = "/imu0",
) -> NoiseOut:
    """Each gyroscope and accelerometer axis's overlapping Allan deviation with 95 % bands, and the noise density,
    bias instability and random walk read from it, each with its 95 % interval (or an upper bound where the curve does
    not show it) and the averaging time it was read at; Kalibr's imu.yaml when the accelerometer was recorded. A
    recording that moves, or is too short a rest, is refused with why (400). Nothing is stored."""
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype not in CSV_TYPES:
        raise problem(415, f"send the rest as text/csv; got {ctype or 'no content type'}")
    body = await request.body()
    check_upload(body, layout)
    out = await upload_work(svc, noise_upload, upload_input(body, name or "rest", upload, fs, layout),
                            svc.settings.max_upload_samples, topic, doing="analysed",
                            too_slow="the noise analysis took too long; try again later, or send a shorter rest",
                            refused=(Refusal,))
    return NoiseOut.model_validate(out)
