"""An uploaded recording calibrated through calib's one door, judged like a live session's result and kept as a
session of its own (POST /devices/{id}/calibrate with a recording)."""

from __future__ import annotations

import asyncio
import uuid

from fastapi.responses import JSONResponse

from calib import __version__
from calib.apply.identity import SensorIdentity
from calib.io.inputs import LAYOUTS, ReadOptions
from calib.json_safe import finite
from calib.judge.judgement import judge

from ..deps import check_method, check_upload, problem, recording_problem
from ..live.history import calibration_history, failed_last_time
from ..service import Service
from ..store import SessionEnd
from ..workers.compute import TooManySamples, calibrate_upload
from .upload_options import upload_input


async def calibrate_uploaded(
    svc: Service,
    device_id: str,
    operator: str,
    body: bytes,
    fs: float | None,
    method: str | None,
    layout: str,
    sensor: dict[str, str | None],
    boot_count: int | None = None,
    options: ReadOptions | None = None,
    accel: bytes | None = None,
    heading_prior_deg: float | None = None,
) -> JSONResponse:
    from calib.estimators.registry import DEFAULT_METHOD

    method = method or DEFAULT_METHOD
    check_method(method)
    check_upload(body, layout, LAYOUTS)
    if layout == "imu_tk" and accel is None:
        raise problem(400, "imu_tk's layout is two files: send the gyroscope's and the accelerometer's as the parts 'gyro' and "
                           "'accel' of a multipart/form-data body")
    inp = upload_input(body, f"upload for {device_id}", options or ReadOptions(), fs, layout, accel)
    try:
        result, used, csv, n_samples = await asyncio.wait_for(
            svc.pool.run(calibrate_upload, inp, method, svc.settings.max_upload_samples,
                         svc.settings.heading_prior_deg if heading_prior_deg is None else heading_prior_deg),
            timeout=svc.settings.compute_timeout_s,
        )
    except TimeoutError:
        raise problem(503, f"calibrating this recording took longer than {svc.settings.compute_timeout_s:g} s; try again later") from None
    except TooManySamples as exc:
        raise problem(413, str(exc)) from None
    except MemoryError:
        raise problem(
            413,
            f"calibrating this recording needs more memory than this service gives a worker "
            f"({svc.settings.worker_memory_mb} MB); send the protocol's part of the recording",
        ) from None
    except Exception as exc:  # calib's errors and whatever else the parser or estimator trips on
        raise recording_problem(exc, "calibrated", upload=True) from None
    res = result.to_json()
    history = await asyncio.to_thread(calibration_history, svc.store, device_id)
    judgement = judge(result, svc.settings.tolerances, history)
    passed = judgement.passed
    checks, departed = judgement.checks_json(), judgement.departures_json()
    sid = uuid.uuid4().hex
    from ..live import guidance as say

    failed_before = set() if passed else await asyncio.to_thread(failed_last_time, svc.store, device_id)
    reason = None if passed else say.out_of_tolerance(judgement.failed_checks, failed_before, hand_turns=used == "paper")
    await asyncio.to_thread(svc.store.upsert_device, device_id)
    await asyncio.to_thread(
        svc.store.create_session,
        sid,
        device_id,
        "upload",
        "computing",
        method,
        operator,
        __version__,
        {"source": "upload", "layout": layout, "fs": fs, "protocol": used, **{k: v for k, v in sensor.items() if v},
         "identity": SensorIdentity(device_id=device_id, sensor_model=sensor.get("sensor_model"), serial=sensor.get("serial"),
                                    firmware=sensor.get("firmware"), boot_count=boot_count,
                                    temperature_c=result.quality.get("temperature_c")).to_json()},
        svc.gateway_name,
    )
    digest = await asyncio.to_thread(svc.store.archive_recording, sid, csv, n_samples)
    end = SessionEnd(
        "done" if passed else "failed",
        None if passed else "out_of_tolerance",
        reason,
        result,
        passed,
        {"checks": checks, "departures": departed, "accuracy": judgement.accuracy, "samples": n_samples},
    )
    await asyncio.to_thread(svc.store.finish_session, sid, end)
    out = {
        **res,
        "session_id": sid,
        "device_id": device_id,
        "protocol": used,
        "accelerometer": result.quality.get("accelerometer"),
        "state": "done" if passed else "failed",
        "passed": passed,
        "checks": checks,
        "departures": departed,
        "accuracy": judgement.accuracy,
        "reason": reason,
        "recording_sha256": digest,
    }
    return JSONResponse(finite(out), status_code=200, headers={"Location": f"/sessions/{sid}"})
