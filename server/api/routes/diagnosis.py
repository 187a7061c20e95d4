"""The model check over HTTP: ``gyrocal diagnose`` (calib.diagnosis) for an uploaded recording or a
stored session.

POST /diagnose and POST /diagnose/report take a CSV body; GET /sessions/{id}/diagnosis,
.../diagnosis/report and .../diagnosis/progress work on a session's archived recording, with the stages
the session used. A diagnosis writes nothing to the store: these are reads (open, or with a token
under --auth-reads). Results are kept in memory by the recording's SHA-256 (see diagnosis_jobs).
"""

from __future__ import annotations

import asyncio
import logging
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi.responses import HTMLResponse, JSONResponse

from calib.errors import RecordingTooLong
from calib.io.inputs import ReadOptions, RecordingInput
from calib.json_safe import finite

from ...deps import (
    AnalysisReader,
    Reader,
    Svc,
    check_session_id,
    check_upload,
    problem,
    read_csv_body,
    recording_problem,
)
from ...live.runner import LiveSession
from ...schemas import Problem
from ...service import Service
from ...store import StoredSession, sha256_hex
from ...workers.compute import TooManySamples
from ...workers.diagnosis import (
    REPORTS_KEPT,
    Busy,
    DiagnosisQueue,
    Lru,
    WorkerDied,
    diagnose_csv,
    digest,
)
from ..diagnosis_schema import DiagnosisOut, DiagnosisProgress
from ..upload_options import Upload, upload_input

log = logging.getLogger(__name__)

REPORT_CSP = "default-src 'none'; img-src data:; style-src 'unsafe-inline'; frame-ancestors 'none'"
RETRY_AFTER_S = 5

Fs = Annotated[float | None, Query(gt=0, le=100000, description="sample rate, Hz (CSV without a time column)")]
Layout = Annotated[str, Query(max_length=16, description="CSV layout: auto, native, imucal")]


# -- the work --------------------------------------------------------------------------------------
class Diagnoser:
    """The service's model checks: the queue of worker processes, the kept results and reports."""

    def __init__(self, svc: Service) -> None:
        self.memory_mb = svc.settings.worker_memory_mb
        self.queue = DiagnosisQueue(timeout_s=svc.settings.compute_timeout_s, memory_mb=svc.settings.worker_memory_mb)
        self.reports = Lru(REPORTS_KEPT)

    async def run(self, key: str, args: tuple[Any, ...], report: bool, upload: bool) -> tuple[dict[str, Any], str | None, bool]:
        """(diagnosis, report HTML or None, whether it was kept from before), or an HTTP problem."""
        q = self.queue
        json_key, html_key = f"json:{key}", f"html:{key}"
        try:
            if report:
                (d, html), kept = await q.get(html_key, diagnose_csv, *args, into=self.reports)
                if q.results.get(json_key) is None:
                    q.results.put(json_key, (d, None))
            else:
                (d, html), kept = await q.get(json_key, diagnose_csv, *args[:-1], None)
        except Busy as exc:
            raise problem(503, str(exc), {"Retry-After": str(RETRY_AFTER_S)}) from None
        except TimeoutError:
            raise problem(503, f"the model check ran over {q.timeout_s:g} s and was stopped: a recording of the protocol "
                           "(about 30 s) takes seconds, this one takes longer than the service allows") from None
        except WorkerDied as exc:
            raise problem(503, f"{exc}; try again") from None
        except (TooManySamples, RecordingTooLong) as exc:
            raise problem(413, str(exc)) from None
        except MemoryError:
            raise problem(413, f"the model check of this recording needs more memory than this service gives a worker "
                           f"({self.memory_mb} MB); send the protocol's part of the recording (about 30-90 s)") from None
        except Exception as exc:  # calib's errors and whatever else the recording trips the diagnosis on
            raise recording_problem(exc, "diagnosed", upload) from None
        return finite(d), html, kept

    def shutdown(self) -> None:
        self.queue.shutdown()


def _upload_args(body: bytes, fs: float | None, layout: str, max_samples: int, upload: ReadOptions) -> tuple[str, tuple[Any, ...]]:
    """The cache key and the worker's arguments of an uploaded recording's model check."""
    check_upload(body, layout)
    key = digest("upload", sha256_hex(body), fs, layout, upload.protocol, upload.sections, upload.gyro_counts_per_dps,
                 upload.accel_counts_per_g)
    return key, (upload_input(body, "uploaded recording", upload, fs, layout), max_samples, None, None, "uploaded recording")


async def _session_source(svc: Service, sid: str) -> tuple[str, StoredSession | None, str | None]:
    """(cache key, stored session row, recording SHA-256) of an ended session with a recording; 404/409 otherwise."""
    check_session_id(sid)
    live = svc.sessions.get(sid)
    if live is not None and not live.machine.finished:
        raise problem(409, f"session {sid} is still running ({live.machine.state}): the model check runs on its recording "
                       "once it has ended")
    row = await asyncio.to_thread(svc.store.session, sid)
    if row is None and live is None:
        raise problem(404, f"no session {sid}")
    digest_ = await asyncio.to_thread(svc.store.recording_sha256, sid)
    if digest_ is None and live is not None and live.csv_bytes:
        digest_ = sha256_hex(live.csv_bytes)  # the store could not be written: the session still holds it
    if digest_ is None:
        state = live.machine.state if live is not None else row["state"] if row is not None else "unknown"
        raise problem(409, f"session {sid} has no recording to check (it is {state}, with no samples archived)")
    stages = _result_stages(row, live)
    return digest("session", digest_, stages), row, digest_


def _result_stages(row: StoredSession | None, live: LiveSession | None) -> list[dict[str, Any]] | None:
    """The stages a session's result was computed on (as stored, or from the live session), None without a result."""
    if row is not None and row["result"]:
        return row["result"].get("stages") or None
    if live is not None and live.machine.result is not None:
        return [s.to_dict() for s in live.machine.result.stages] or None
    return None


async def _session_args(svc: Service, sid: str, row: StoredSession | None, report: bool) -> tuple[Any, ...]:
    got = await asyncio.to_thread(svc.store.recording, sid)
    live = svc.sessions.get(sid)
    csv = got[0] if got is not None else (live.csv_bytes if live is not None else None)
    if csv is None:
        raise problem(409, f"session {sid} has no recording to check")
    stages = _result_stages(row, live)
    device = row["device_id"] if row is not None else live.device.id if live is not None else ""
    info = (row["info"] if row is not None else None) or {}
    full_scale = info.get("gyro_full_scale_dps") or (live.machine.full_scale if live is not None else None)
    return (RecordingInput(csv, f"session {sid}", ReadOptions(layout="native")), svc.settings.max_diagnose_samples, stages,
            full_scale, f"session {sid} ({device})" if report else None)


def _json(d: dict[str, Any], kept: bool, sha: str | None = None) -> JSONResponse:
    headers = {"X-Diagnosis-Cache": "hit" if kept else "miss"}
    if sha:
        headers["X-Recording-SHA256"] = sha
    return JSONResponse(d, headers=headers)


def _html(html: str | None, kept: bool) -> HTMLResponse:
    return HTMLResponse(html or "", headers={"Content-Security-Policy": REPORT_CSP, "X-Diagnosis-Cache": "hit" if kept else "miss"})


# -- the routes ------------------------------------------------------------------------------------
router = APIRouter()


def _diagnoser(request: Request) -> Diagnoser:
    diagnoser: Diagnoser = request.app.state.diagnoser
    return diagnoser


Diag = Annotated[Diagnoser, Depends(_diagnoser)]

Responses = dict[int | str, dict[str, Any]]
P: dict[str, Any] = {"model": Problem}
busy: Responses = {503: {**P, "description": "as many model checks as the service runs are under way (Retry-After), or one ran "
                                  "over the time limit"}}
csv_body = {"requestBody": {"required": True, "content": {
    "text/csv": {"schema": {"type": "string", "description": "a recording: native (t,gx,gy,gz,...) or imucal layout"}}}}}
upload_responses: Responses = {
    400: {**P, "description": "the recording cannot be read"},
    401: {**P, "description": "reads need a token (--auth-reads)"},
    413: {**P, "description": "the recording is too large, spans too long, or needs more memory than a worker has"},
    415: {**P, "description": "the body is not CSV (text/csv)"},
    429: {**P, "description": "too many model checks without a token from this address (Retry-After)"},
    422: {**P, "description": "invalid parameters, or the protocol is not in the recording (the missing stage is named)"},
    **busy,
}
session_responses: Responses = {
    401: {**P, "description": "reads need a token (--auth-reads)"},
    404: {**P, "description": "unknown session"},
    409: {**P, "description": "the session is running, or has no recording"},
    422: {**P, "description": "the protocol is not in the session's recording"},
    **busy,
}
html_ok: Responses = {200: {"content": {"text/html": {}}, "description": "the HTML report, figures embedded"}}

@router.post("/diagnose", response_model=DiagnosisOut, responses=upload_responses, openapi_extra=csv_body, tags=["diagnosis"])
async def diagnose_upload(
    svc: Svc, diag: Diag, request: Request, _: AnalysisReader, upload: Upload, fs: Fs = None, layout: Layout = "auto"
) -> JSONResponse:
    """Compare an uploaded recording with its simulation: where it departs, which physical effect
    explains it, how much the fit improves (as `gyrocal diagnose --json`). Nothing is stored."""
    key, args = _upload_args(await read_csv_body(request), fs, layout, svc.settings.max_diagnose_samples, upload)
    d, _, kept = await diag.run(key, args, report=False, upload=True)
    return _json(d, kept)


@router.post(
    "/diagnose/report", response_class=Response, responses={**html_ok, **upload_responses}, openapi_extra=csv_body, tags=["diagnosis"]
)
async def diagnose_upload_report(
    svc: Svc, diag: Diag, request: Request, _: AnalysisReader, upload: Upload, fs: Fs = None, layout: Layout = "auto"
) -> HTMLResponse:
    """The HTML report of an uploaded recording's model check (as `gyrocal diagnose --report`)."""
    key, args = _upload_args(await read_csv_body(request), fs, layout, svc.settings.max_diagnose_samples, upload)
    _d, html, kept = await diag.run(key, args, report=True, upload=True)
    return _html(html, kept)


@router.get("/sessions/{session_id}/diagnosis", response_model=DiagnosisOut, responses=session_responses, tags=["diagnosis"])
async def diagnose_session(svc: Svc, diag: Diag, session_id: str, _: Reader) -> JSONResponse:
    """The model check of an ended session's archived recording, with the stages the session used.
    Computed at the first request (seconds), then kept: X-Diagnosis-Cache says which."""
    key, row, sha = await _session_source(svc, session_id)
    kept = diag.queue.results.get(f"json:{key}")
    if kept is not None:
        return _json(finite(kept[0]), True, sha)
    args = await _session_args(svc, session_id, row, report=False)
    d, _, was_kept = await diag.run(key, args, report=False, upload=False)
    return _json(d, was_kept, sha)


@router.get(
    "/sessions/{session_id}/diagnosis/report", response_class=Response, responses={**html_ok, **session_responses}, tags=["diagnosis"]
)
async def diagnose_session_report(svc: Svc, diag: Diag, session_id: str, _: Reader) -> HTMLResponse:
    """The HTML report of a session's model check: the recording's features against its simulations
    before and after the effects are modelled, still means, closures, time base, every test."""
    key, row, _sha = await _session_source(svc, session_id)
    kept = diag.reports.get(f"html:{key}")
    if kept is not None:
        return _html(kept[1], True)
    args = await _session_args(svc, session_id, row, report=True)
    _d, html, was_kept = await diag.run(key, args, report=True, upload=False)
    return _html(html, was_kept)


@router.get(
    "/sessions/{session_id}/diagnosis/progress",
    response_model=DiagnosisProgress,
    responses={k: v for k, v in session_responses.items() if k != 422 and k != 503},
    tags=["diagnosis"],
)
async def diagnosis_progress(svc: Svc, diag: Diag, session_id: str, _: Reader) -> DiagnosisProgress:
    """Where the session's model check is, for a page to show while GET .../diagnosis runs."""
    key, _row, _sha = await _session_source(svc, session_id)
    if f"json:{key}" in diag.queue.results:
        return DiagnosisProgress(state="done", fraction=1.0, stage="done")
    job = diag.queue.jobs.get(f"json:{key}") or diag.queue.jobs.get(f"html:{key}")
    if job is None:
        return DiagnosisProgress(state="idle")
    return DiagnosisProgress(state=job.state, fraction=round(job.fraction, 3), stage=job.stage,
                             elapsed_s=round(job.elapsed_s, 2))
