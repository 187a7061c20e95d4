"""GET /sessions/{id}/plot: the before/after traces of a session's calibration, for the wizard page.

The traces come from calib.plots.calibration_traces: the rate magnitude and the orientation (angle
from the start pose) integrated from the raw readings and from the calibrated ones, decimated so that
a browser can draw them as SVG.
"""

from __future__ import annotations

import asyncio
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request

from calib.json_safe import finite
from calib.recording import Recording
from calib.result import CalibrationResult

from ...deps import Reader, check_session_id, problem, service_of
from ...schemas import SessionPlot


def session_traces(rec: Recording, res: CalibrationResult, max_points: int) -> SessionPlot:
    """The JSON body of GET /sessions/{id}/plot for a recording and its result."""
    from calib.plots import calibration_traces

    traces = calibration_traces(rec, res, max_points=max_points)
    return SessionPlot.model_validate(finite({**traces, "k": res.k, "b": res.b, "method": res.method}))


router = APIRouter()


RESPONSES: dict[int | str, dict[str, Any]] = {
    404: {"description": "unknown session, or no archived recording"},
    409: {"description": "the session has no result (yet)"},
}

@router.get("/sessions/{session_id}/plot", response_model=SessionPlot, responses=RESPONSES, tags=["sessions"])
async def session_plot(
    session_id: str,
    request: Request,
    _: Reader,
    max_points: Annotated[int, Query(ge=50, le=5000, description="at most this many points per trace")] = 800,
) -> SessionPlot:
    """Rate magnitude and orientation (angle from the start pose) before and after calibration,
    the angle swept in each turn, and the turn intervals; times in s from the recording's start."""
    from calib.errors import GyrocalError
    from calib.io.readers import parse_recording_text

    check_session_id(session_id)
    svc = service_of(request)
    live = svc.sessions.get(session_id)
    if live is not None:
        res = live.machine.result
        if res is None:
            raise problem(409, f"session {session_id} has no result to plot (it is {live.machine.state})")
        rec = await asyncio.to_thread(live.machine.recording)
    else:
        row = await asyncio.to_thread(svc.store.session, session_id)
        if row is None:
            raise problem(404, f"no session {session_id}")
        stored = row.get("result")
        if not stored:
            raise problem(409, f"session {session_id} has no result to plot (it is {row['state']})")
        try:
            res = CalibrationResult.from_dict(stored)
        except (KeyError, TypeError, ValueError) as exc:
            raise problem(409, f"the stored result of session {session_id} cannot be read ({type(exc).__name__}: {exc})") from None
        got = await asyncio.to_thread(svc.store.recording, session_id)
        if got is None:
            raise problem(404, f"no archived recording for session {session_id}")
        try:
            rec = await asyncio.to_thread(parse_recording_text, got[0].decode(), None, "native", f"session {session_id}")
        except GyrocalError as exc:
            raise problem(409, f"the archived recording of session {session_id} cannot be read: {exc}") from None
    try:
        return await asyncio.to_thread(session_traces, rec, res, max_points)
    except (KeyError, ValueError, IndexError, GyrocalError) as exc:
        raise problem(409, f"the result of session {session_id} cannot be plotted ({type(exc).__name__}: {exc})") from None
