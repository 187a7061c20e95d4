"""The calibration service's HTTP API (FastAPI).

Reads are open to whoever can reach the service (it binds to 127.0.0.1 by default) unless the
service runs with --auth-reads; every write needs an operator's bearer token.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
import time
import uuid
from contextlib import asynccontextmanager
from datetime import datetime, timezone
from pathlib import Path
from typing import Annotated, Any, AsyncIterator

from fastapi import Depends, FastAPI, HTTPException, Query, Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, JSONResponse, StreamingResponse
from fastapi.routing import APIRoute
from fastapi.staticfiles import StaticFiles
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from pydantic import ValidationError
from sqlalchemy.exc import SQLAlchemyError

from calib import __version__

from . import models as M
from .auth import AuthError, Authenticator, SignIns, Throttled
from .config import Settings
from .devices import DEVICE_ID_RE, Device, DeviceManager
from .events import Event, dumps, finite
from .compute import ComputePool, TooManySamples, calibrate_upload
from .runner import LiveSession
from .session import END_STATES, GuidedSession, evaluate_result
from .security import HostCheck, SecurityHeaders, add_docs
from .throttle import TokenBucket, retry_after_header
from .store import DecisionConflict, NotAcceptable, NotFound, SessionEnd, Store, StoreError

log = logging.getLogger(__name__)

# not text/plain: a web page may POST that anywhere without a CORS preflight, text/csv it may not
CSV_TYPES = ("text/csv", "application/csv")
SESSION_ID_RE = re.compile(r"^[0-9a-f]{32}$")
KEEP_FINISHED = 200  # finished live sessions kept in memory for their event streams


class Service:
    """Everything the API works with: settings, store, operators, devices, live sessions."""

    def __init__(self, settings: Settings, store: Store | None = None, devices: DeviceManager | None = None) -> None:
        self.settings = settings
        self.store = store or Store(settings.db_url)
        self.auth = Authenticator(self.store, settings.api_token, settings.token_ttl_s)
        self.sign_ins = SignIns(self.auth)
        self.anonymous_analyses = TokenBucket(settings.anonymous_analyses_per_min, burst=3)
        self.devices = devices or DeviceManager()
        self.pool = ComputePool(memory_mb=settings.worker_memory_mb)
        self.sessions: dict[str, LiveSession] = {}
        self.active: dict[str, str] = {}  # device id -> running session id
        self.started = time.time()
        self.integrity: dict[str, Any] | None = None  # the last verification of the store's hash chains
        self._integrity_task: asyncio.Task[None] | None = None

    async def verify_store(self) -> dict[str, Any]:
        """Verify the store's hash chains now (in a thread); the result is what /health reports."""
        report = await asyncio.to_thread(self.store.verify)
        self.integrity = {**report.to_dict(), "checked_at": datetime.now(timezone.utc).isoformat()}
        if not report.ok:
            log.error("the store's history was tampered with: %s", report.broken)
        return self.integrity

    async def _verify_periodically(self) -> None:
        while True:
            with contextlib.suppress(Exception):
                await self.verify_store()
            await asyncio.sleep(self.settings.integrity_check_s)

    async def startup(self) -> None:
        self._integrity_task = asyncio.get_running_loop().create_task(self._verify_periodically())
        await self.pool.start()
        n = await asyncio.to_thread(
            self.store.fail_unfinished_sessions,
            "The service was restarted while this calibration ran. Start a new calibration.",
        )
        if n:
            log.warning("%d sessions left open by a previous run were marked failed", n)
        for dev in self.devices.devices.values():
            await asyncio.to_thread(self.store.upsert_device, dev.id, name=dev.name, address=dev.address, transport=dev.transport)

    async def shutdown(self) -> None:
        if self._integrity_task is not None:
            self._integrity_task.cancel()
        for live in list(self.sessions.values()):
            if not live.machine.finished:
                with contextlib.suppress(Exception):
                    await asyncio.wait_for(live.shutdown(), timeout=10.0)
            live.broadcaster.close()
        await self.devices.close()
        self.sign_ins.close()
        self.pool.shutdown()
        self.store.close()

    def _session_ended(self, live: LiveSession) -> None:
        if self.active.get(live.device.id) == live.id:
            del self.active[live.device.id]
        finished = [s for s in self.sessions.values() if s.machine.finished]
        for old in finished[: max(0, len(finished) - KEEP_FINISHED)]:
            old.broadcaster.close()
            self.sessions.pop(old.id, None)


# -- helpers -------------------------------------------------------------------------------------
def _problem(status: int, detail: str, headers: dict[str, str] | None = None) -> HTTPException:
    return HTTPException(status_code=status, detail=detail, headers=headers)


def _recording_problem(exc: Exception, doing: str, upload: bool) -> HTTPException:
    """calib's errors (and anything else a recording trips the work on) as 4xx: the recording is at fault,
    never the service. ``doing``: "calibrated" or "diagnosed". A stored session's recording that cannot be
    read is a conflict (409), an uploaded one a bad request (400)."""
    from calib.errors import GyrocalError, ProtocolError, RecordingError

    if isinstance(exc, ProtocolError):
        return _problem(422, str(exc))
    if isinstance(exc, RecordingError):
        return _problem(400, str(exc)) if upload else _problem(409, f"the archived recording cannot be read: {exc}")
    if isinstance(exc, GyrocalError):
        return _problem(422, str(exc))
    log.warning("a recording could not be %s: %r", doing, exc, exc_info=not upload)
    if upload:
        return _problem(400, f"the recording cannot be {doing} ({type(exc).__name__}: {exc}); send a native or imucal CSV "
                        "of the protocol")
    return _problem(422, f"this session's recording cannot be {doing} ({type(exc).__name__}: {exc})")


def _check_upload(body: bytes, layout: str) -> None:
    """Refuse an uploaded CSV that names an unknown layout (422) or is empty (400)."""
    if layout not in ("auto", "native", "imucal"):
        raise _problem(422, f"unknown layout {layout!r}: choose auto, native or imucal")
    if not body.strip():
        raise _problem(400, "the CSV body is empty: send a recording (header t,gx,gy,gz,... or gyr_x,gyr_y,gyr_z,...)")


def _service(request: Request) -> Service:
    return request.app.state.service


bearer = HTTPBearer(auto_error=False, description="an operator's token from POST /auth/login, or GYROCAL_API_TOKEN")


async def _token_operator(svc: Service, token: str | None) -> str | None:
    if not token:
        return None
    return await asyncio.to_thread(svc.auth.operator_for, token)


async def require_operator(
    request: Request, creds: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]
) -> str:
    """The signed-in operator of a write request (401 otherwise)."""
    svc = _service(request)
    op = await _token_operator(svc, creds.credentials if creds else None)
    if op is None:
        raise _problem(
            401,
            "this needs a signed-in operator: send 'Authorization: Bearer <token>' with a token from POST /auth/login"
            if creds is None
            else "the token is unknown or expired: sign in again (POST /auth/login)",
            {"WWW-Authenticate": "Bearer"},
        )
    request.state.operator = op
    return op


async def read_access(
    request: Request,
    access_token: Annotated[str | None, Query(description="token for readers that cannot send headers (EventSource), when reads need one")] = None,
) -> str | None:
    """Reads are open unless the service runs with --auth-reads (then the schema says so too: see _openapi)."""
    svc = _service(request)
    if not svc.settings.auth_reads:
        return None
    auth = request.headers.get("authorization", "")
    token = auth[7:].strip() if auth[:7].lower() == "bearer " else access_token
    op = await _token_operator(svc, token)
    if op is None:
        raise _problem(401, "this service needs a token for reads too: sign in (POST /auth/login)", {"WWW-Authenticate": "Bearer"})
    return op


async def analysis_quota(request: Request, reader: Annotated[str | None, Depends(read_access)]) -> str | None:
    """Uploaded recordings analysed without an operator's token are rate-limited per client address (429)."""
    svc = _service(request)
    if reader is not None:
        return reader
    auth = request.headers.get("authorization", "")
    if auth[:7].lower() == "bearer " and await _token_operator(svc, auth[7:].strip()):
        return None
    wait = svc.anonymous_analyses.take(request.client.host if request.client else "unknown")
    if wait > 0:
        raise _problem(429, f"anonymous model checks are limited to {svc.settings.anonymous_analyses_per_min:g} a minute from one "
                       "address: try again shortly, or sign in (POST /auth/login) and send the token", retry_after_header(wait))
    return None


Reader = Annotated[str | None, Depends(read_access)]
AnalysisReader = Annotated[str | None, Depends(analysis_quota)]
Operator = Annotated[str, Depends(require_operator)]


def _check_device_id(device_id: str) -> None:
    if not DEVICE_ID_RE.match(device_id):
        raise _problem(404, f"no device {device_id!r}: device ids are letters, digits and . _ : - (see GET /devices)")


def _check_session_id(sid: str) -> None:
    if not SESSION_ID_RE.match(sid):
        raise _problem(404, f"no session {sid!r}: session ids are 32 hex digits, as returned when a session starts")


async def _current(svc: Service, device_id: str) -> dict[str, Any] | None:
    rec = await asyncio.to_thread(svc.store.current_calibration, device_id)
    return None if rec is None else rec.to_dict()


async def _device_out(svc: Service, dev: Device | None, row: dict[str, Any] | None, detail: bool = False) -> dict[str, Any]:
    device_id = dev.id if dev else row["id"]  # type: ignore[index]
    row = row or {}
    info = dev.info if dev else {}
    out: dict[str, Any] = {
        "id": device_id,
        "name": (dev.name if dev else None) or row.get("name"),
        "transport": dev.transport if dev else row.get("transport"),
        "address": (dev.address if dev else None) or row.get("address"),
        "connected": bool(dev and dev.connected),
        "available": dev is not None,
        "simulated": bool(dev and dev.simulated),
        "scenario": dev.scenario if dev else None,
        "sensor_model": info.get("sensor_model") or row.get("sensor_model"),
        "firmware": info.get("firmware") or row.get("firmware"),
        "serial": info.get("serial") or row.get("serial"),
        "battery_pct": info.get("battery_pct"),
        "active_session": svc.active.get(device_id),
        "current_calibration": await _current(svc, device_id),
        "last_seen": row.get("last_seen"),
    }
    if detail:
        out["simulated_truth"] = dev.simulated_truth if dev else None
        out["info"] = finite(dict(info))
        out["recent_sessions"] = [
            {k: s[k] for k in ("id", "kind", "state", "reason_code", "passed", "decision", "started_at", "ended_at")}
            for s in await asyncio.to_thread(svc.store.sessions, device_id, 10)
        ]
    return out


def _stored_snapshot(row: dict[str, Any]) -> dict[str, Any]:
    info = row.get("info") or {}
    return {
        "session_id": row["id"],
        "device_id": row["device_id"],
        "kind": row["kind"],
        "event": "state",
        "state": row["state"],
        "phase": None,
        "prompt": row.get("reason"),
        "reason_code": row["reason_code"],
        "reason": row["reason"],
        "result": row["result"],
        "passed": row["passed"],
        "checks": info.get("checks") or [],
        "warnings": info.get("warnings") or [],
        "turns": info.get("turns") or {},
        "decision": row["decision"],
        "calibration_id": None,
        "method": row["method"],
        "operator": row["operator"],
        "started_at": row["started_at"],
        "ended_at": row["ended_at"],
    }


async def _session_snapshot(svc: Service, sid: str) -> dict[str, Any]:
    live = svc.sessions.get(sid)
    if live is not None:
        snap = live.machine.snapshot("state")
        snap["kind"] = "live"
        snap["operator"] = live.operator
        return snap
    row = await asyncio.to_thread(svc.store.session, sid)
    if row is None:
        raise _problem(404, f"no session {sid}")
    return _stored_snapshot(row)


# -- the app -------------------------------------------------------------------------------------
class BodyLimit:
    """Refuses request bodies above a size with 413: by Content-Length at once, and a body sent without one
    (chunked) is read up to the limit before the route sees it, so every route answers 413 alike."""

    def __init__(self, app: Any, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def _refuse(self, scope: Any, receive: Any, send: Any, status: int, msg: str) -> None:
        await JSONResponse({"detail": msg}, status_code=status)(scope, receive, send)

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = dict(scope.get("headers") or [])
        too_big = f"the request body is larger than {self.max_bytes // (1024 * 1024)} MiB; send a shorter recording"
        length = headers.get(b"content-length")
        if length is not None:
            try:
                n = int(length)
            except ValueError:
                n = -1
            if n < 0:
                await self._refuse(scope, receive, send, 400, "the Content-Length header is not a number")
            elif n > self.max_bytes:
                await self._refuse(scope, receive, send, 413, too_big)
            else:
                await self.app(scope, receive, send)
            return
        if b"chunked" not in headers.get(b"transfer-encoding", b"").lower():
            await self.app(scope, receive, send)
            return
        body, more = bytearray(), True
        while more:
            message = await receive()
            if message["type"] != "http.request":
                return  # the client went away
            body += message.get("body", b"")
            more = message.get("more_body", False)
            if len(body) > self.max_bytes:
                await self._refuse(scope, receive, send, 413, too_big)
                return
        replayed = False

        async def replay() -> Any:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": bytes(body), "more_body": False}
            return await receive()

        await self.app(scope, replay, send)


def create_app(settings: Settings | None = None, service: Service | None = None) -> FastAPI:
    """The FastAPI application; the Service (store, devices) is created from settings if not given."""
    settings = settings or (service.settings if service else Settings())
    svc = service or Service(settings)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        await svc.startup()
        try:
            yield
        finally:
            await svc.shutdown()

    app = FastAPI(
        title="gyrocal calibration service",
        version=__version__,
        description=(
            "Calibrates the gyroscopes of wearable IMUs: guided live sessions over BLE, uploads of recordings, "
            "and a per-device, append-only history of accepted calibrations. Model g = K m + b "
            "(g true rate, m reading, deg/s). Writes need `Authorization: Bearer <token>` (POST /auth/login)."
        ),
        lifespan=lifespan,
        docs_url=None,  # served from this computer's files by security.add_docs, never from a CDN
        redoc_url=None,
        responses={
            400: {"model": M.Problem, "description": "malformed request (unreadable body or headers)"},
            413: {"model": M.Problem, "description": "request body too large"},
            422: {"model": M.Problem, "description": "invalid request"},
        },
    )
    app.state.service = svc
    app.add_middleware(BodyLimit, max_bytes=settings.max_body_bytes)
    app.add_middleware(HostCheck, allowed=settings.allowed_hosts)
    app.add_middleware(SecurityHeaders)  # outermost: every answer carries the headers, refusals too

    @app.exception_handler(StoreError)
    async def _store_error(request: Request, exc: StoreError) -> JSONResponse:
        return JSONResponse({"detail": f"the store is unavailable: {exc}. Try again; nothing was changed."}, status_code=503)

    @app.exception_handler(SQLAlchemyError)
    async def _db_error(request: Request, exc: SQLAlchemyError) -> JSONResponse:
        log.exception("store error")
        return JSONResponse({"detail": f"the store is unavailable ({type(exc).__name__}). Try again; nothing was changed."}, status_code=503)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = []
        for e in exc.errors():
            loc = ".".join(str(p) for p in e.get("loc", ()) if p != "body")
            errors.append(f"{loc}: {e.get('msg')}" if loc else str(e.get("msg")))
        return JSONResponse({"detail": "; ".join(errors) or "invalid request"}, status_code=422)

    R404 = {404: {"model": M.Problem, "description": "unknown device or session"}}
    R401 = {401: {"model": M.Problem, "description": "no or bad operator token"}}
    R409 = {409: {"model": M.Problem, "description": "not possible in the current state"}}
    R503 = {503: {"model": M.Problem, "description": "the store could not be written; nothing changed, try again"}}

    # -- service --------------------------------------------------------------------------------
    @app.get("/health", response_model=M.Health, tags=["service"])
    async def health(
        verify: Annotated[bool, Query(description="verify the store's hash chains now (at most every few seconds) "
                                                  "instead of reporting the last periodic check")] = False,
    ) -> dict[str, Any]:
        """Liveness, what the service runs on and whether the store's history is intact (never needs a token)."""
        integrity = svc.integrity
        if integrity is None or (verify and time.time() - datetime.fromisoformat(integrity["checked_at"]).timestamp() > 2.0):
            integrity = await svc.verify_store()
        return {
            "status": "ok" if integrity["ok"] else "tampered",
            "integrity": integrity,
            "version": __version__,
            "store": svc.store.dialect,
            "schema_version": await asyncio.to_thread(svc.store.schema_version),
            "devices": len(svc.devices.devices),
            "active_sessions": len(svc.active),
            "auth_reads": settings.auth_reads,
        }

    @app.post("/auth/login", response_model=M.LoginOut, tags=["auth"], responses={
        401: {"model": M.Problem, "description": "unknown operator or wrong secret (audited)"},
        429: {"model": M.Problem, "description": "too many failed sign-ins for this operator or from this address (Retry-After)"},
    })
    async def login(body: M.LoginIn, request: Request) -> dict[str, Any]:
        """Sign an operator in: name and secret in, bearer token out. After 5 failures for a name (20 from one
        address) each attempt waits 1, 2, 4, ... s (at most 5 min) after the last failure."""
        client = request.client.host if request.client else "unknown"
        try:
            token, expires = await svc.sign_ins.sign_in(body.operator, body.secret, client)
        except Throttled as exc:
            raise _problem(429, str(exc), retry_after_header(exc.retry_after_s)) from None
        except AuthError as exc:
            raise _problem(401, str(exc)) from None
        return {"token": token, "token_type": "bearer", "operator": body.operator, "expires_at": expires.isoformat()}

    @app.post("/auth/logout", status_code=204, responses=R401, tags=["auth"])
    async def logout(request: Request, operator: Operator, creds: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]) -> Response:
        """Revoke the token of this request."""
        if creds is not None:
            await asyncio.to_thread(svc.auth.sign_out, creds.credentials, operator)
        return Response(status_code=204)

    @app.get("/auth/me", response_model=M.Me, responses=R401, tags=["auth"])
    async def me(operator: Operator) -> dict[str, str]:
        """The operator a token belongs to."""
        return {"operator": operator}

    # -- devices --------------------------------------------------------------------------------
    @app.get("/devices", response_model=list[M.DeviceOut], tags=["devices"])
    async def list_devices(_: Reader) -> list[dict[str, Any]]:
        """Known devices: the connectable ones (simulated, scanned) and those in the store's history."""
        rows = {r["id"]: r for r in await asyncio.to_thread(svc.store.devices)}
        ids = list(svc.devices.devices) + [i for i in rows if i not in svc.devices.devices]
        return [await _device_out(svc, svc.devices.get(i), rows.get(i)) for i in ids]

    @app.post("/devices/scan", response_model=M.ScanOut, responses=R401, tags=["devices"])
    async def scan(operator: Operator, timeout: Annotated[float, Query(gt=0, le=30, description="scan time, s")] = 5.0) -> dict[str, Any]:
        """Scan for wearables (BLE when the service runs with --ble); returns those found, each with its id."""
        try:
            found = await svc.devices.scan(timeout)
        except Exception as exc:
            raise _problem(503, f"the Bluetooth scan failed ({exc}); check that Bluetooth is on") from None
        for dev in found:
            await asyncio.to_thread(svc.store.upsert_device, dev.id, name=dev.name, address=dev.address, transport=dev.transport)
        await asyncio.to_thread(svc.store.audit, operator, "devices.scan", None, None, {"found": [d.id for d in found]})
        rows = {r["id"]: r for r in await asyncio.to_thread(svc.store.devices)}
        return {"devices": [await _device_out(svc, d, rows.get(d.id)) for d in found]}

    @app.get("/devices/{device_id}", response_model=M.DeviceDetail, responses=R404, tags=["devices"])
    async def get_device(device_id: str, _: Reader) -> dict[str, Any]:
        """One device: connection, current calibration, recent sessions; simulated ones show their truth."""
        _check_device_id(device_id)
        dev = svc.devices.get(device_id)
        row = await asyncio.to_thread(svc.store.device, device_id)
        if dev is None and row is None:
            raise _problem(404, f"no device {device_id!r}; see GET /devices or POST /devices/scan")
        return await _device_out(svc, dev, row, detail=True)

    @app.get("/devices/{device_id}/calibration", response_model=M.CalibrationOut, responses=R404, tags=["calibrations"])
    async def current_calibration(device_id: str, _: Reader) -> dict[str, Any]:
        """The device's current calibration: its latest accepted one."""
        _check_device_id(device_id)
        cur = await _current(svc, device_id)
        if cur is None:
            raise _problem(404, f"device {device_id!r} has no accepted calibration yet")
        return cur

    @app.get("/devices/{device_id}/calibrations", response_model=list[M.CalibrationOut], responses=R404, tags=["calibrations"])
    async def calibrations(device_id: str, _: Reader) -> list[dict[str, Any]]:
        """Every accepted calibration of the device, newest first (nothing is ever overwritten)."""
        _check_device_id(device_id)
        if svc.devices.get(device_id) is None and await asyncio.to_thread(svc.store.device, device_id) is None:
            raise _problem(404, f"no device {device_id!r}")
        return [r.to_dict() for r in await asyncio.to_thread(svc.store.calibrations, device_id)]

    @app.post(
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
                },
            }
        },
        tags=["sessions"],
    )
    async def calibrate(
        device_id: str,
        request: Request,
        response: Response,
        operator: Operator,
        fs: Annotated[float | None, Query(gt=0, le=100000, description="sample rate, Hz (CSV without a time column)")] = None,
        method: Annotated[M.Method | None, Query(description="estimator: closure (default) or paper")] = None,
        layout: Annotated[str, Query(max_length=16, description="CSV layout: auto, native, imucal")] = "auto",
        sensor_model: Annotated[str | None, Query(min_length=1, max_length=128, pattern=M.SENSOR_TEXT,
                                                  description="the sensor an uploaded recording came from (e.g. ICM-20948); "
                                                  "needed before its result can be accepted")] = None,
        firmware: Annotated[str | None, Query(min_length=1, max_length=128, pattern=M.SENSOR_TEXT,
                                              description="the device's firmware version, for an uploaded recording")] = None,
    ) -> Any:
        """Start a guided live session (JSON body or none) → 202; or calibrate an uploaded CSV → 200."""
        _check_device_id(device_id)
        ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
        body = await request.body()
        if ctype in CSV_TYPES:
            return await _offline(svc, device_id, operator, body, fs, method.value if method else None, layout, {"sensor_model": sensor_model, "firmware": firmware})
        if ctype and ctype != "application/json" and body:
            raise _problem(415, f"send a JSON body (application/json) to start a live session or a CSV (text/csv) to calibrate a recording; got {ctype}")
        opts = M.SessionStart()
        if body.strip():
            try:
                opts = M.SessionStart.model_validate_json(body)
            except ValidationError as exc:
                raise _problem(422, "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" if e["loc"] else e["msg"] for e in exc.errors())) from None
        chosen = opts.method or method
        live = await _start_live(svc, device_id, operator, chosen.value if chosen else None, opts.max_attempts)
        url = f"/sessions/{live.id}"
        response.headers["Location"] = url
        return {"session_id": live.id, "device_id": device_id, "state": live.machine.state, "url": url, "events": f"{url}/events"}

    # -- sessions -------------------------------------------------------------------------------
    @app.get("/sessions/{session_id}", response_model=M.SessionOut, responses=R404, tags=["sessions"])
    async def get_session(session_id: str, _: Reader) -> dict[str, Any]:
        """A session's full state; `result` once computed."""
        _check_session_id(session_id)
        return finite(await _session_snapshot(svc, session_id))

    @app.get(
        "/sessions/{session_id}/events",
        responses={200: {"content": {"text/event-stream": {}}, "description": "Server-Sent Events: each a full session snapshot"}, **R404},
        response_class=StreamingResponse,
        tags=["sessions"],
    )
    async def session_events(
        session_id: str,
        request: Request,
        _: Reader,
        last_event_id: Annotated[int | None, Query(ge=0, description="resume after this event id (instead of the Last-Event-ID header)")] = None,
    ) -> StreamingResponse:
        """Server-Sent Events of a session: state changes, prompts, live angle, stillness progress,
        warnings and the result, each a full snapshot with an id (reconnect with Last-Event-ID)."""
        _check_session_id(session_id)
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
        row = await asyncio.to_thread(svc.store.session, session_id)
        if row is None:
            raise _problem(404, f"no session {session_id}")
        snap = finite(_stored_snapshot(row))

        async def once() -> AsyncIterator[bytes]:
            yield Event(0, "state", dumps(snap)).encode()

        return StreamingResponse(once(), media_type="text/event-stream", headers=headers)

    @app.get(
        "/sessions/{session_id}/recording",
        responses={200: {"content": {"text/csv": {}}, "description": "the archived raw recording (native CSV)"}, **R404},
        response_class=Response,
        tags=["sessions"],
    )
    async def session_recording(session_id: str, _: Reader) -> Response:
        """The session's archived raw recording; header X-Recording-SHA256 is its checksum."""
        _check_session_id(session_id)
        got = await asyncio.to_thread(svc.store.recording, session_id)
        if got is None:
            raise _problem(404, f"no archived recording for session {session_id}")
        data, digest = got
        return Response(data, media_type="text/csv", headers={"X-Recording-SHA256": digest,
                                                              "Content-Disposition": f'attachment; filename="{session_id}.csv"'})

    @app.post("/sessions/{session_id}/cancel", response_model=M.SessionOut, responses={**R401, **R404, **R409}, tags=["sessions"])
    async def cancel(session_id: str, operator: Operator) -> dict[str, Any]:
        """Stop a running session; it ends `cancelled` and nothing is stored as a calibration."""
        _check_session_id(session_id)
        live = svc.sessions.get(session_id)
        if live is None:
            await _session_snapshot(svc, session_id)  # 404 if unknown
            raise _problem(409, "the session has ended already; nothing to cancel")
        if not live.cancel(f"Cancelled by {operator}."):
            raise _problem(409, f"the session has ended already ({live.machine.state}); nothing to cancel")
        await asyncio.to_thread(svc.store.audit, operator, "session.cancel", live.device.id, session_id)
        await live.wait()
        return finite(await _session_snapshot(svc, session_id))

    @app.post("/sessions/{session_id}/accept", response_model=M.AcceptOut, responses={**R401, **R404, **R409, **R503}, tags=["sessions"])
    async def accept(session_id: str, operator: Operator, body: M.DecisionIn | None = None) -> dict[str, Any]:
        """Store the session's result as the device's current calibration (a new row in its history)."""
        _check_session_id(session_id)
        live = svc.sessions.get(session_id)
        snap = await _session_snapshot(svc, session_id)
        if snap["state"] != "done":
            why = snap.get("reason") or f"it is {snap['state']}"
            raise _problem(409, f"only a finished session within tolerances can be accepted; this one is {snap['state']}: {why}")
        if not snap.get("passed"):
            raise _problem(409, "the result is outside the tolerances and cannot become the device's calibration")
        if live is not None:
            await live.wait()
        try:
            rec = await asyncio.to_thread(
                svc.store.accept,
                session_id,
                operator,
                snap["result"],
                end=live.session_end() if live is not None else None,
                sensor_model=(live.device.info.get("sensor_model") if live else None) or (body.sensor_model if body else None),
                firmware=(live.device.info.get("firmware") if live else None) or (body.firmware if body else None),
                recording_csv=(live.csv_bytes if live else None),
                n_samples=(live.machine.buf.n if live else 0),
            )
        except (DecisionConflict, NotAcceptable) as exc:
            raise _problem(409, str(exc)) from None
        except NotFound as exc:
            raise _problem(404, str(exc)) from None
        except (StoreError, SQLAlchemyError) as exc:
            log.warning("accept of %s failed: %s", session_id, exc)
            raise _problem(
                503,
                f"the calibration could not be stored ({type(exc).__name__}); the previous calibration stays current. "
                "Try accepting again.",
            ) from None
        if body is not None and body.note:
            await asyncio.to_thread(svc.store.audit, operator, "session.note", rec.device_id, session_id, {"note": body.note})
        if live is not None:
            live.machine.decide("accepted", rec.id)
            live.broadcaster.close()
        return {"session_id": session_id, "calibration": rec.to_dict()}

    @app.post("/sessions/{session_id}/discard", response_model=M.SessionOut, responses={**R401, **R404, **R409, **R503}, tags=["sessions"])
    async def discard(session_id: str, operator: Operator, body: M.DecisionIn | None = None) -> dict[str, Any]:
        """Discard a finished session's result; it stays in the store for audit and never becomes current."""
        _check_session_id(session_id)
        live = svc.sessions.get(session_id)
        snap = await _session_snapshot(svc, session_id)
        if snap["state"] not in END_STATES:
            raise _problem(409, "the session is still running: cancel it first")
        if live is not None:
            await live.wait()
        try:
            await asyncio.to_thread(svc.store.discard_session, session_id, operator,
                                    live.session_end() if live is not None else None)
        except DecisionConflict as exc:
            raise _problem(409, str(exc)) from None
        except NotFound as exc:
            raise _problem(404, str(exc)) from None
        except (StoreError, SQLAlchemyError) as exc:
            log.warning("discard of %s failed: %s", session_id, exc)
            raise _problem(503, f"the decision could not be stored ({type(exc).__name__}); try again") from None
        if body is not None and body.note:
            await asyncio.to_thread(svc.store.audit, operator, "session.note", snap["device_id"], session_id, {"note": body.note})
        if live is not None:
            live.machine.decide("discarded", None)
            live.broadcaster.close()
        return finite(await _session_snapshot(svc, session_id))

    @app.get("/devices/{device_id}/sessions", response_model=list[M.SessionOut], responses=R404, tags=["sessions"])
    async def device_sessions(device_id: str, _: Reader, limit: Annotated[int, Query(ge=1, le=500)] = 50) -> list[dict[str, Any]]:
        """A device's sessions, newest first, whatever their outcome (kept for audit)."""
        _check_device_id(device_id)
        rows = await asyncio.to_thread(svc.store.sessions, device_id, limit)
        out = []
        for r in rows:
            live = svc.sessions.get(r["id"])
            # a running session's row is written at its start and end: show its live state instead
            out.append(finite(await _session_snapshot(svc, r["id"]) if live is not None else _stored_snapshot(r)))
        return out

    @app.get("/audit", response_model=list[M.AuditEntry], responses=R401, tags=["service"])
    async def audit(
        operator: Operator,
        device_id: Annotated[str | None, Query(max_length=128, pattern=DEVICE_ID_RE.pattern)] = None,
        limit: Annotated[int, Query(ge=1, le=1000)] = 200,
    ) -> list[dict[str, Any]]:
        """The audit log, newest first: who did what, when, on which device (needs a token)."""
        return await asyncio.to_thread(svc.store.audit_log, device_id, limit)

    from .diagnosis_routes import register as register_diagnosis_routes
    from .plot_routes import register as register_plot_routes

    register_plot_routes(app)  # before the page is mounted at /, which would shadow later routes
    register_diagnosis_routes(app)
    add_docs(app)
    _mount_static(app, settings)
    _openapi(app, settings)
    return app


OPEN_ALWAYS = {"/health", "/auth/login"}


def _openapi(app: FastAPI, settings: Settings) -> None:
    """The published schema: reads declare the bearer token only when the service requires it (--auth-reads)."""
    default = app.openapi

    def schema() -> dict[str, Any]:
        if app.openapi_schema is None:
            doc = default()
            if settings.auth_reads:
                for path, ops in doc.get("paths", {}).items():
                    for op in ops.values():
                        if isinstance(op, dict) and "security" not in op and path not in OPEN_ALWAYS:
                            op["security"] = [{"HTTPBearer": []}]
                            op.setdefault("responses", {}).setdefault("401", {"description": "reads need a token (--auth-reads)"})
            app.openapi_schema = doc
        return app.openapi_schema

    app.openapi = schema  # type: ignore[method-assign]


async def _start_live(svc: Service, device_id: str, operator: str, method: str | None, max_attempts: int | None) -> LiveSession:
    from calib.api import available_methods

    if method is not None and method not in available_methods():
        raise _problem(422, f"unknown method {method!r}: choose one of {', '.join(available_methods())}")
    dev = svc.devices.get(device_id)
    if dev is None:
        known = await asyncio.to_thread(svc.store.device, device_id)
        if known is None:
            raise _problem(404, f"no device {device_id!r}; see GET /devices or scan with POST /devices/scan")
        if known.get("transport") == "ble" and svc.devices.ble:
            dev = svc.devices.add_ble_address(device_id)
        else:
            raise _problem(409, f"device {device_id!r} is not reachable by this service (known from uploads only); scan for it first")
    if device_id in svc.active:
        raise _problem(409, f"device {device_id!r} is already in a calibration session ({svc.active[device_id]}); one at a time")
    sid = uuid.uuid4().hex
    machine = GuidedSession(sid, device_id, svc.settings, max_attempts=max_attempts, method=method)
    svc.active[device_id] = sid  # claimed before the first await: a second request gets 409
    try:
        await asyncio.to_thread(
            svc.store.create_session, sid, device_id, "live", "connecting", machine.method, operator, __version__,
            {"transport": dev.transport, "scenario": dev.scenario},
        )
    except Exception:
        svc.active.pop(device_id, None)
        raise
    live = LiveSession(machine, dev, svc.store, svc.settings, __version__, operator, on_end=svc._session_ended, pool=svc.pool)
    svc.sessions[sid] = live
    live.start()
    return live


async def _offline(svc: Service, device_id: str, operator: str, body: bytes, fs: float | None, method: str | None, layout: str,
                   sensor: dict[str, str | None]) -> JSONResponse:
    from calib.api import DEFAULT_METHOD, available_methods

    method = method or DEFAULT_METHOD
    if method not in available_methods():
        raise _problem(422, f"unknown method {method!r}: choose one of {', '.join(available_methods())}")
    _check_upload(body, layout)
    source = f"upload for {device_id}"
    try:
        res, csv, n_samples = await asyncio.wait_for(
            svc.pool.run(calibrate_upload, body, fs, layout, method, source, svc.settings.max_upload_samples),
            timeout=svc.settings.compute_timeout_s,
        )
    except asyncio.TimeoutError:
        raise _problem(503, f"calibrating this recording took longer than {svc.settings.compute_timeout_s:g} s; try again later") from None
    except TooManySamples as exc:
        raise _problem(413, str(exc)) from None
    except MemoryError:
        raise _problem(413, f"calibrating this recording needs more memory than this service gives a worker "
                       f"({svc.settings.worker_memory_mb} MB); send the protocol's part of the recording") from None
    except Exception as exc:  # calib's errors and whatever else the parser or estimator trips on
        raise _recording_problem(exc, "calibrated", upload=True) from None
    res = finite(res)
    checks = evaluate_result(res, svc.settings.tolerances)
    failures = [c["text"] for c in checks if not c["ok"]]
    passed = not failures
    sid = uuid.uuid4().hex
    from . import guidance as say

    reason = None if passed else say.out_of_tolerance(failures)
    await asyncio.to_thread(svc.store.upsert_device, device_id)
    await asyncio.to_thread(svc.store.create_session, sid, device_id, "upload", "computing", method, operator, __version__,
                            {"source": "upload", "layout": layout, "fs": fs, **{k: v for k, v in sensor.items() if v}})
    digest = await asyncio.to_thread(svc.store.archive_recording, sid, csv, n_samples)
    end = SessionEnd("done" if passed else "failed", None if passed else "out_of_tolerance", reason, res, passed,
                     {"checks": checks, "samples": n_samples})
    await asyncio.to_thread(svc.store.finish_session, sid, end)
    out = {
        **res,
        "session_id": sid,
        "device_id": device_id,
        "state": "done" if passed else "failed",
        "passed": passed,
        "checks": checks,
        "reason": reason,
        "recording_sha256": digest,
    }
    return JSONResponse(finite(out), status_code=200, headers={"Location": f"/sessions/{sid}"})


_PLACEHOLDER = """<!doctype html><html lang="en"><head><meta charset="utf-8"><title>gyrocal</title></head>
<body style="font-family: sans-serif; max-width: 40em; margin: 3em auto">
<h1>gyrocal calibration service</h1>
<p>The service runs. The API is described at <a href="/docs">/docs</a> (OpenAPI: <a href="/openapi.json">/openapi.json</a>);
devices are listed at <a href="/devices">/devices</a>.</p></body></html>"""


class PageFiles(StaticFiles):
    """The wizard's files at /. A method the page does not take is answered 405 with the Allow header of the API
    route at that path, if any (otherwise the catch-all mount would answer every path's OPTIONS, PUT, ...)."""

    def __init__(self, app: FastAPI, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.api = app

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        if scope["type"] == "http" and scope["method"] not in ("GET", "HEAD"):
            allowed: set[str] = set()
            for route in self.api.routes:
                if isinstance(route, APIRoute) and route.path_regex.match(scope["path"]):
                    allowed |= route.methods
            allow = ", ".join(sorted(allowed or {"GET", "HEAD"}))
            await JSONResponse({"detail": f"{scope['method']} is not allowed on {scope['path']}; allowed: {allow}"},
                               status_code=405, headers={"Allow": allow})(scope, receive, send)
            return
        await super().__call__(scope, receive, send)


def _mount_static(app: FastAPI, settings: Settings) -> None:
    static = settings.static_dir
    if static is None:
        static = Path(__file__).resolve().parents[1] / "webui" / "static"
    if Path(static).is_dir() and (Path(static) / "index.html").is_file():
        app.mount("/", PageFiles(app, directory=str(static), html=True), name="webui")
        return

    @app.get("/", response_class=HTMLResponse, include_in_schema=False)
    async def index() -> str:
        return _PLACEHOLDER
