"""What a session keeps for use elsewhere: GET /sessions/{id}/recording (the raw recording, native CSV) and
GET /sessions/{id}/sections (the rests and turns its calibration was computed on, as imucal's section list). Given
together to ``gyrocal calibrate --sections`` (``calibrate-kit --sections`` for a kit's wearables), or to the page's
upload, they give the calibration the session gave."""

from __future__ import annotations

import asyncio

from fastapi import APIRouter, Response
from fastapi.responses import JSONResponse

from ... import schemas as M
from ...deps import R404, Reader, Svc, check_session_id, problem
from ...store import StoredSession, sha256_hex

router = APIRouter()


@router.get(
    "/sessions/{session_id}/recording",
    responses={200: {"content": {"text/csv": {}}, "description": "the archived raw recording (native CSV)"}, **R404},
    response_class=Response,
    tags=["sessions"],
)
async def session_recording(svc: Svc, session_id: str, _: Reader) -> Response:
    """The session's archived raw recording; header X-Recording-SHA256 is its checksum."""
    check_session_id(session_id)
    got = await asyncio.to_thread(svc.store.recording, session_id)
    live = svc.sessions.get(session_id)
    if got is None and live is not None and live.machine.finished and live.csv_bytes:
        # ended a moment ago and not yet in the store: the same bytes the store is about to keep
        got = (live.csv_bytes, sha256_hex(live.csv_bytes))
    if got is None:
        raise problem(404, f"no archived recording for session {session_id}")
    data, digest = got
    return Response(
        data,
        media_type="text/csv",
        headers={"X-Recording-SHA256": digest, "Content-Disposition": f'attachment; filename="{session_id}.csv"'},
    )


@router.get(
    "/sessions/{session_id}/sections",
    response_model=list[M.SectionOut],
    responses={200: {"description": "imucal's section list over the archived recording's samples: "
                     '[{"label": "still_1", "start": 0, "end": 612}, {"label": "x_rot", ...}, ...]'}, **R404},
    tags=["sessions"],
)
async def session_sections(svc: Svc, session_id: str, _: Reader) -> JSONResponse:
    """The rests and turns the session's calibration was computed on (a live session's: the turns its guidance took,
    not a try that was asked again), as imucal's section list over its archived recording's samples."""
    check_session_id(session_id)
    live = svc.sessions.get(session_id)
    sections = live.sections if live is not None and live.machine.finished else None
    if sections is None and (row := await asyncio.to_thread(svc.store.session, session_id)) is not None:
        sections = _stored(row)
    if not sections:
        raise problem(404, f"no sections for session {session_id}: only a guided session that was calibrated keeps them "
                           "(it may still be running, or have ended before it was calibrated)")
    return JSONResponse(sections, headers={"Content-Disposition": f'attachment; filename="{session_id}.sections.json"'})


def _stored(row: StoredSession) -> list[dict[str, str | int]] | None:
    """A stored live session's sections, as it kept them (an upload's are the file's own, or found in it again)."""
    kept = (row["info"] or {}).get("sections")
    return None if kept is None else list(kept)
