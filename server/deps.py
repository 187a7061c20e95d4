"""What the routes share: the service of a request, who is asking (operator or reader, with the anonymous
analysis quota), id checks, problems (4xx answers that say what to do) and the published error responses."""

from __future__ import annotations

import asyncio
import logging
import re
from typing import Annotated, Any

from fastapi import Depends, HTTPException, Query, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from calib.io.inputs import LAYOUTS

from . import schemas as M
from .devices import DEVICE_ID_RE
from .service import Service
from .throttle import retry_after_header

log = logging.getLogger(__name__)

# not text/plain: a web page may POST that anywhere without a CORS preflight, text/csv it may not
CSV_TYPES = ("text/csv", "application/csv")
SESSION_ID_RE = re.compile(r"^[0-9a-f]{32}$")
R404: dict[int | str, dict[str, Any]] = {404: {"model": M.Problem, "description": "unknown device or session"}}
R401: dict[int | str, dict[str, Any]] = {401: {"model": M.Problem, "description": "no or bad operator token"}}
R409: dict[int | str, dict[str, Any]] = {409: {"model": M.Problem, "description": "not possible in the current state"}}
R503: dict[int | str, dict[str, Any]] = {
    503: {"model": M.Problem, "description": "the store could not be written; nothing changed, try again"}
}


def problem(status: int, detail: str, headers: dict[str, str] | None = None) -> HTTPException:
    return HTTPException(status_code=status, detail=detail, headers=headers)


def check_method(method: str) -> None:
    """422 naming the estimators when none is named ``method`` (calib.estimators.registry says which there are)."""
    from calib.errors import GyrocalError
    from calib.estimators.registry import check_method as check

    try:
        check(method)
    except GyrocalError as exc:
        raise problem(422, str(exc)) from None


class RecordingProblem(HTTPException):
    """A recording the service could not read or calibrate: the problem carries the same ``code`` as the command
    line's ``{"error": {"code"}}`` (``calib.errors.error_code``)."""

    def __init__(self, status: int, detail: str, code: str) -> None:
        super().__init__(status_code=status, detail=detail)
        self.code = code


def recording_problem(exc: Exception, doing: str, upload: bool) -> HTTPException:
    """calib's errors (and anything else a recording trips the work on) as 4xx: the recording is at fault,
    never the service. ``doing``: "calibrated" or "diagnosed". A stored session's recording that cannot be
    read is a conflict (409), an uploaded one a bad request (400)."""
    from calib.errors import GyrocalError, ProtocolError, RecordingError, error_code

    if isinstance(exc, ProtocolError):
        return RecordingProblem(422, str(exc), error_code(exc))
    if isinstance(exc, RecordingError):
        if upload:
            return RecordingProblem(400, str(exc), error_code(exc))
        return problem(409, f"the archived recording cannot be read: {exc}")
    if isinstance(exc, GyrocalError):
        return RecordingProblem(422, str(exc), error_code(exc))
    log.warning("a recording could not be %s: %r", doing, exc, exc_info=not upload)
    if upload:
        return problem(400, f"the recording cannot be {doing} ({type(exc).__name__}: {exc}); send a native or imucal CSV of the protocol")
    return problem(422, f"this session's recording cannot be {doing} ({type(exc).__name__}: {exc})")


CSV_LAYOUTS = tuple(layout for layout in LAYOUTS if layout != "imu_tk")  # one CSV file (imu_tk's layout is two)


def check_upload(body: bytes, layout: str, layouts: tuple[str, ...] = CSV_LAYOUTS) -> None:
    """Refuse an upload that names a layout the route does not read (422) or is empty (400)."""
    if layout not in layouts:
        raise problem(422, f"unknown layout {layout!r}: choose {', '.join(layouts[:-1])} or {layouts[-1]}")
    if not body.strip():
        raise problem(400, "the CSV body is empty: send a recording (header t,gx,gy,gz,... or gyr_x,gyr_y,gyr_z,...)")


async def read_csv_body(request: Request) -> bytes:
    """The request's body, which must be a CSV recording (415 otherwise)."""
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    body = await request.body()
    if ctype not in CSV_TYPES:
        raise problem(415, f"send the recording as CSV (Content-Type: text/csv), native (t,gx,gy,gz,...) or imucal layout; "
                       f"got {ctype or 'no content type'}")
    return body


IMU_TK_PARTS = {"gyro": "imu_tk's gyroscope file", "accel": "imu_tk's accelerometer file"}


async def read_imu_tk_parts(request: Request, layout: str) -> tuple[bytes, bytes]:
    """imu_tk's two files from a multipart/form-data body: its parts 'gyro' and 'accel' (415 or 422 otherwise)."""
    if layout != "imu_tk":
        raise problem(415, "a multipart/form-data body carries imu_tk's two files: add layout=imu_tk, or send one recording "
                           "as text/csv")
    form = await request.form()
    parts = []
    for name, what in IMU_TK_PARTS.items():
        item = form.get(name)
        if item is None:
            raise problem(422, f"the multipart body has no part '{name}' ({what}): send the gyroscope's file as 'gyro' and "
                               "the accelerometer's as 'accel'")
        parts.append(item.encode() if isinstance(item, str) else await item.read())
    return parts[0], parts[1]


def service_of(request: Request) -> Service:
    return request.app.state.service


bearer = HTTPBearer(auto_error=False, description="an operator's token from POST /auth/login, or GYROCAL_API_TOKEN")


async def token_operator(svc: Service, token: str | None) -> str | None:
    if not token:
        return None
    return await asyncio.to_thread(svc.auth.operator_for, token)


async def require_operator(request: Request, creds: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]) -> str:
    """The signed-in operator of a write request (401 otherwise)."""
    svc = service_of(request)
    op = await token_operator(svc, creds.credentials if creds else None)
    if op is None:
        raise problem(
            401,
            "this needs a signed-in operator: send 'Authorization: Bearer <token>' with a token from POST /auth/login"
            if creds is None
            else "the token is unknown or expired: sign in again (POST /auth/login)",
            {"WWW-Authenticate": "Bearer"},
        )
    request.state.operator = op
    return op


def bearer_token(request: Request) -> str | None:
    """The token of an ``Authorization: Bearer`` header (None when the request sends no such header)."""
    auth = request.headers.get("authorization", "")
    return auth[7:].strip() if auth[:7].lower() == "bearer " else None


async def read_access(
    request: Request,
    access_token: Annotated[
        str | None, Query(description="token for readers that cannot send headers (EventSource), when reads need one")
    ] = None,
) -> str | None:
    """Reads are open unless the service runs with --auth-reads (then the schema says so too: see publish_openapi)."""
    svc = service_of(request)
    if not svc.settings.auth_reads:
        return None
    token = bearer_token(request)
    op = await token_operator(svc, token if token is not None else access_token)
    if op is None:
        raise problem(401, "this service needs a token for reads too: sign in (POST /auth/login)", {"WWW-Authenticate": "Bearer"})
    return op


async def analysis_quota(request: Request, reader: Annotated[str | None, Depends(read_access)]) -> str | None:
    """Uploaded recordings analysed without an operator's token are rate-limited per client address (429)."""
    svc = service_of(request)
    if reader is not None:
        return reader
    token = bearer_token(request)
    if token and await token_operator(svc, token):
        return None
    wait = svc.anonymous_analyses.take(request.client.host if request.client else "unknown")
    if wait > 0:
        raise problem(
            429,
            f"anonymous model checks are limited to {svc.settings.anonymous_analyses_per_min:g} a minute from one "
            "address: try again shortly, or sign in (POST /auth/login) and send the token",
            retry_after_header(wait),
        )
    return None


Reader = Annotated[str | None, Depends(read_access)]


AnalysisReader = Annotated[str | None, Depends(analysis_quota)]


Operator = Annotated[str, Depends(require_operator)]


def check_device_id(device_id: str) -> None:
    if not DEVICE_ID_RE.match(device_id):
        raise problem(404, f"no device {device_id!r}: device ids are letters, digits and . _ : - (see GET /devices)")


def check_session_id(sid: str) -> None:
    if not SESSION_ID_RE.match(sid):
        raise problem(404, f"no session {sid!r}: session ids are 32 hex digits, as returned when a session starts")


Svc = Annotated[Service, Depends(service_of)]
