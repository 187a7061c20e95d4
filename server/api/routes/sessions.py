"""Calibration sessions: start one live (or calibrate an uploaded recording), follow it, cancel it,
accept or discard its result."""

from __future__ import annotations

import asyncio
import logging
import uuid
from collections.abc import AsyncIterator, Callable
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request, Response
from fastapi.responses import StreamingResponse
from pydantic import ValidationError
from sqlalchemy.exc import SQLAlchemyError

from calib import __version__

from ... import schemas as M
from ...deps import (
    CSV_TYPES,
    R401,
    R404,
    R409,
    R503,
    Operator,
    Reader,
    Svc,
    check_device_id,
    check_method,
    check_session_id,
    problem,
    read_imu_tk_parts,
)
from ...devices import Device
from ...live.codes import END_STATES
from ...live.events import Event, dumps
from ...live.runner import LiveSession
from ...live.session import GuidedSession
from ...live.snapshot import stored_snapshot
from ...live.snapshot_schema import SessionOut
from ...live.turn_watch import LiveAngle
from ...service import Service
from ...store import DecisionConflict, NotAcceptable, NotFound, StoreError, store_trouble
from ..upload_options import Upload
from ..upload_result import calibrate_uploaded
from ..views import claim_device, decided_snapshot, reachable_device, remote_gateway, runs_elsewhere, session_snapshot, stored_kit

# The section list travels in the URL: 4000 characters (about 80 sections) stay under what the HTTP server reads
# as one request line even percent-encoded at 12 bytes a character; a longer one gets a 422, not a dropped connection.

log = logging.getLogger(__name__)
router = APIRouter()


@router.post(
    "/devices/{device_id}/calibrate",
    status_code=202,
    response_model=M.SessionStarted,
    responses={
        200: {"model": M.OfflineResult, "description": "a text/csv recording was calibrated"},
        400: {"model": M.Problem, "description": "the recording cannot be read"},
        413: {"model": M.Problem, "description": "the recording is too large"},
        415: {"model": M.Problem, "description": "unsupported body type"},
        **R401, **R404, **R409, **R503,
    },
    openapi_extra={
        "requestBody": {
            "required": False,
            "content": {
                "application/json": {"schema": M.SessionStart.model_json_schema()},
                "text/csv": {"schema": {"type": "string", "description": "a recording: native (t,gx,gy,gz,...) or imucal layout"}},
                "multipart/form-data": {"schema": {
                    "type": "object", "required": ["gyro", "accel"],
                    "description": "with layout=imu_tk: imu_tk's two files, rows 't x y z' of raw counts",
                    "properties": {"gyro": {"type": "string", "format": "binary", "description": "the gyroscope's file"},
                                   "accel": {"type": "string", "format": "binary", "description": "the accelerometer's file"}},
                }},
            },
        }
    },
    tags=["sessions"],
)
async def calibrate(svc: Svc, 
    device_id: str,
    request: Request,
    response: Response,
    operator: Operator,
    upload: Upload,
    fs: Annotated[float | None, Query(gt=0, le=100000, description="sample rate, Hz (CSV without a time column)")] = None,
    method: Annotated[M.Method | None, Query(description="estimator: closure (default) or paper")] = None,
    layout: Annotated[str, Query(max_length=16, description="CSV layout: auto, native, imucal; imu_tk for imu_tk's two "
                                 "files (a multipart/form-data body)")] = "auto",
    sensor_model: Annotated[str | None, Query(min_length=1, max_length=128, pattern=M.SENSOR_TEXT,
                                              description="the sensor an uploaded recording came from (e.g. ICM-20948); "
                                              "needed before its result can be accepted")] = None,
    firmware: Annotated[str | None, Query(min_length=1, max_length=128, pattern=M.SENSOR_TEXT,
                                          description="the device's firmware version, for an uploaded recording")] = None,
    serial: Annotated[str | None, Query(min_length=1, max_length=128, pattern=M.SENSOR_TEXT,
                                        description="the sensor's serial or chip id, for an uploaded recording")] = None,
    boot_count: Annotated[int | None, Query(ge=0, le=0xFFFFFFFF,
                                            description="the device's power-up count the recording was made in")] = None,
    heading_prior_deg: Annotated[float | None, Query(
        ge=0, le=10, description="for an uploaded recording: how far (1 sigma, deg) the device's heading may be off after "
        "each turn, where the site knows it (closure); default the service's setting, else learned from the turns")] = None,
) -> Any:
    """Start a guided live session (JSON body or none) → 202; or calibrate an uploaded CSV (or imu_tk's two files,
    multipart) → 200."""
    check_device_id(device_id)
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype == "multipart/form-data":
        body, accel = await read_imu_tk_parts(request, layout)
    else:
        body, accel = await request.body(), None
    if ctype in CSV_TYPES or ctype == "multipart/form-data":
        return await calibrate_uploaded(
            svc,
            device_id,
            operator,
            body,
            fs,
            method.value if method else None,
            layout,
            {"sensor_model": sensor_model, "firmware": firmware, "serial": serial},
            boot_count,
            upload,
            accel,
            heading_prior_deg,
        )
    if ctype and ctype != "application/json" and body:
        raise problem(
            415, f"send a JSON body (application/json) to start a live session or a CSV (text/csv) to calibrate a recording; got {ctype}"
        )
    opts = M.SessionStart()
    if body.strip():
        try:
            opts = M.SessionStart.model_validate_json(body)
        except ValidationError as exc:
            raise problem(
                422, "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" if e["loc"] else e["msg"] for e in exc.errors())
            ) from None
    chosen = opts.method or method
    live = await start_live(svc, device_id, operator, chosen.value if chosen else None, opts.max_attempts)
    url = f"/sessions/{live.id}"
    response.headers["Location"] = url
    return {"session_id": live.id, "device_id": device_id, "state": live.machine.state, "url": url, "events": f"{url}/events"}


@router.get("/sessions/{session_id}", response_model=SessionOut, responses=R404, tags=["sessions"])
async def get_session(svc: Svc, session_id: str, _: Reader) -> SessionOut:
    """A session's full state; `result` once computed."""
    check_session_id(session_id)
    return await session_snapshot(svc, session_id)


@router.get(
    "/sessions/{session_id}/events",
    responses={200: {"content": {"text/event-stream": {}}, "description": "Server-Sent Events: each a full session snapshot"}, **R404},
    response_class=StreamingResponse,
    tags=["sessions"],
)
async def session_events(
    svc: Svc,
    session_id: str,
    request: Request,
    _: Reader,
    last_event_id: Annotated[
        int | None, Query(ge=0, description="resume after this event id (instead of the Last-Event-ID header)")
    ] = None,
) -> StreamingResponse:
    """Server-Sent Events of a session: state changes, prompts, live angle, stillness progress,
    warnings and the result, each a full snapshot with an id (reconnect with Last-Event-ID)."""
    check_session_id(session_id)
    header = request.headers.get("last-event-id")
    if header is not None:
        try:
            last_event_id = int(header)
        except ValueError:
            last_event_id = None
    live = svc.sessions.get(session_id)
    headers = {"Cache-Control": "no-cache", "X-Accel-Buffering": "no"}
    if live is not None:
        return StreamingResponse(live.broadcaster.stream(last_event_id), media_type="text/event-stream", headers=headers)
    if (kit := svc.kits.get(session_id)) is not None:
        return StreamingResponse(kit.broadcaster.stream(last_event_id), media_type="text/event-stream", headers=headers)
    row = await asyncio.to_thread(svc.store.session, session_id)
    if row is None:
        snap = await stored_kit(svc, session_id, f"no session {session_id}")
    elif (gateway := runs_elsewhere(svc, row)) is not None:
        snap = stored_snapshot(row)
        remote = await remote_gateway(svc, gateway)
        return StreamingResponse(svc.events.follow(session_id, snap, remote).stream(last_event_id),
                                 media_type="text/event-stream", headers=headers)
    else:
        snap = stored_snapshot(row)

    async def once() -> AsyncIterator[bytes]:
        yield Event(0, "state", dumps(snap.model_dump(mode="json", exclude_unset=True))).encode()

    return StreamingResponse(once(), media_type="text/event-stream", headers=headers)


@router.post("/sessions/{session_id}/cancel", response_model=SessionOut, responses={**R401, **R404, **R409}, tags=["sessions"])
async def cancel(svc: Svc, session_id: str, operator: Operator) -> SessionOut:
    """Stop a running session; it ends `cancelled` and nothing is stored as a calibration."""
    check_session_id(session_id)
    live = svc.sessions.get(session_id)
    if live is None:
        snap = await session_snapshot(svc, session_id)  # 404 if unknown
        if snap.remote is not None and snap.state not in END_STATES:
            raise problem(409, f"this session runs on gateway {snap.remote.gateway!r}, where the wearable is: cancel it there")
        raise problem(409, "the session has ended already; nothing to cancel")
    if not live.cancel(f"Cancelled by {operator}."):
        raise problem(409, f"the session has ended already ({live.machine.state}); nothing to cancel")
    await asyncio.to_thread(svc.store.audit, operator, "session.cancel", live.device.id, session_id)
    await live.wait()
    return await session_snapshot(svc, session_id)


@router.post("/sessions/{session_id}/accept", response_model=M.AcceptOut, responses={**R401, **R404, **R409, **R503}, tags=["sessions"])
async def accept(svc: Svc, session_id: str, operator: Operator, body: M.DecisionIn | None = None) -> M.AcceptOut:
    """Store the session's result as the device's current calibration (a new row in its history)."""
    check_session_id(session_id)
    if session_id in svc.kits:
        raise problem(409, f"this is a kit's session: accept its wearables together with POST /kits/{session_id}/accept")
    live = svc.sessions.get(session_id)
    snap = await decided_snapshot(svc, session_id)
    if snap.state != "done":
        why = snap.reason or f"it is {snap.state}"
        raise problem(409, f"only a finished session within tolerances can be accepted; this one is {snap.state}: {why}")
    if not snap.passed:
        raise problem(409, "the result is outside the tolerances and cannot become the device's calibration")
    if live is not None:
        await live.wait()
    try:
        rec = await asyncio.to_thread(
            svc.store.accept,
            session_id,
            operator,
            live.machine.result if live is not None else None,
            end=live.session_end() if live is not None else None,
            identity=live.identity if live is not None else None,
            sensor_model=(live.device.info.get("sensor_model") if live else None) or (body.sensor_model if body else None),
            firmware=(live.device.info.get("firmware") if live else None) or (body.firmware if body else None),
            recording_csv=(live.csv_bytes if live else None),
            n_samples=(live.csv_samples if live else 0),
        )
    except (DecisionConflict, NotAcceptable, NotFound):
        raise  # 409 / 404 with the store's own sentence (server.main)
    except (StoreError, SQLAlchemyError) as exc:
        log.warning("accept of %s failed: %s", session_id, exc)
        raise problem(
            503,
            f"the calibration could not be stored: {store_trouble(exc)}. The previous calibration stays current; try "
            "accepting again.",
        ) from None
    if body is not None and body.note:
        await asyncio.to_thread(svc.store.audit, operator, "session.note", rec.device_id, session_id, {"note": body.note})
    if live is not None:
        live.machine.decide("accepted", rec.id)
        live.broadcaster.close()
    svc.events.fleet_changed("calibration", rec.device_id)
    svc.events.decided(session_id)
    return M.AcceptOut(session_id=session_id, calibration=rec)


@router.post("/sessions/{session_id}/discard", response_model=SessionOut, responses={**R401, **R404, **R409, **R503}, tags=["sessions"])
async def discard(svc: Svc, session_id: str, operator: Operator, body: M.DecisionIn | None = None) -> SessionOut:
    """Discard a finished session's result; it stays in the store for audit and never becomes current."""
    check_session_id(session_id)
    live = svc.sessions.get(session_id)
    snap = await decided_snapshot(svc, session_id)
    if snap.state not in END_STATES:
        raise problem(409, "the session is still running: cancel it first")
    if live is not None:
        await live.wait()
    try:
        await asyncio.to_thread(svc.store.discard_session, session_id, operator, live.session_end() if live is not None else None)
    except (DecisionConflict, NotFound):
        raise  # 409 / 404 with the store's own sentence (server.main)
    except (StoreError, SQLAlchemyError) as exc:
        log.warning("discard of %s failed: %s", session_id, exc)
        raise problem(503, f"the decision could not be stored: {store_trouble(exc)}. Nothing was changed; try again.") from None
    if body is not None and body.note:
        await asyncio.to_thread(svc.store.audit, operator, "session.note", snap.device_id, session_id, {"note": body.note})
    if live is not None:
        live.machine.decide("discarded", None)
        live.broadcaster.close()
    svc.events.decided(session_id)
    return await session_snapshot(svc, session_id)


async def live_angle_of(svc: Service, device_id: str) -> LiveAngle:
    """The live angle a session shows: through the device's accepted calibration, or raw when it has none
    (or the store cannot say: the session still runs, without a target on its gauge)."""
    try:
        cur = await asyncio.to_thread(svc.store.current_calibration, device_id)
    except (StoreError, SQLAlchemyError) as exc:
        log.warning("no accepted calibration for the live angle of %s: %s", device_id, exc)
        return LiveAngle()
    return LiveAngle() if cur is None else LiveAngle.from_calibration(cur.k, cur.K, checks_turns=cur.source == "live")


async def start_live(svc: Service, device_id: str, operator: str, method: str | None, max_attempts: int | None) -> LiveSession:
    if method is not None:
        check_method(method)
    if (cannot_keep := svc.storage_problem()) is not None:
        raise problem(503, f"no calibration can be started: {cannot_keep}")
    dev = await reachable_device(svc, device_id)
    sid = uuid.uuid4().hex
    await claim_device(svc, device_id, sid, "one at a time", announce=False)
    live = await new_live(svc, dev, sid, operator, method, max_attempts, svc._session_ended)
    live.start()
    return live


async def new_live(svc: Service, dev: Device, sid: str, operator: str, method: str | None, max_attempts: int | None,
                   on_end: Callable[[LiveSession], None]) -> LiveSession:
    """A guided session ``sid`` on the claimed device ``dev``, its row stored, registered, not yet started; the device
    is released if it cannot be made."""
    try:
        machine = GuidedSession(sid, dev.id, svc.settings, max_attempts=max_attempts, method=method,
                                live_angle=await live_angle_of(svc, dev.id))
        await asyncio.to_thread(svc.store.create_session, sid, dev.id, "live", "connecting", machine.method, operator,
                                __version__, {"transport": dev.transport, "scenario": dev.scenario}, svc.gateway_name)
    except Exception:
        svc.release_device(dev.id, sid)
        raise
    svc.events.fleet_changed("session", dev.id)
    live = LiveSession(machine, dev, svc.store, svc.settings, __version__, operator, on_end=on_end, pool=svc.pool,
                       relay=svc.events.relay)
    svc.sessions[sid] = live
    return live
