"""The application: the FastAPI app of a Service, with its middleware, error answers, routers, the API docs
and the wizard page. `create_app()` is what `gyrocal serve` runs."""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import SQLAlchemyError

from calib import __version__
from calib.apply.identity import WrongSensor

from . import schemas as M
from .api import page
from .api.routes import (
    apply,
    archive,
    audit,
    auth,
    devices,
    diagnosis,
    fleet,
    health,
    identify,
    kits,
    noise,
    plots,
    sessions,
    verify,
    watch,
    write_back,
)
from .config import Settings
from .deps import RecordingProblem
from .middleware import BodyLimit
from .security import HostCheck, SecurityHeaders, add_docs
from .service import Service
from .store import DecisionConflict, NotAcceptable, NotFound, StoreError, StoreFull

log = logging.getLogger(__name__)


def create_app(settings: Settings | None = None, service: Service | None = None) -> FastAPI:
    """The FastAPI application; the Service (store, devices) is created from settings if not given."""
    settings = settings or (service.settings if service else Settings())
    svc = service or Service(settings)
    diagnoser = diagnosis.Diagnoser(svc)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        await svc.startup()
        try:
            yield
        finally:
            await svc.shutdown()
            diagnoser.shutdown()

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
    app.state.diagnoser = diagnoser
    app.add_middleware(BodyLimit, max_bytes=settings.max_body_bytes)
    app.add_middleware(HostCheck, allowed=settings.allowed_hosts)
    app.add_middleware(SecurityHeaders)  # outermost: every answer carries the headers, refusals too
    _error_answers(app)
    for module in (health, auth, devices, sessions, archive, kits, write_back, identify, audit, plots, diagnosis, apply, verify, watch,
                   noise, fleet):
        app.include_router(module.router)
    add_docs(app)
    page.mount_page(app, settings)  # last: the page's files at / would shadow later routes
    publish_openapi(app, settings)
    return app


def _error_answers(app: FastAPI) -> None:
    """Store outages are 503 (nothing changed), invalid requests 422 with one readable sentence."""

    @app.exception_handler(StoreError)
    async def _store_error(request: Request, exc: StoreError) -> JSONResponse:
        return JSONResponse({"detail": f"the store is unavailable: {exc}. Try again; nothing was changed."}, status_code=503)

    @app.exception_handler(StoreFull)
    async def _store_full(request: Request, exc: StoreFull) -> JSONResponse:
        return JSONResponse({"detail": f"{exc}. This request changed nothing; try again once space is freed."}, status_code=503)

    # the store's refusals that are the request's doing, not an outage: the message says what happened
    @app.exception_handler(DecisionConflict)
    @app.exception_handler(NotAcceptable)
    @app.exception_handler(WrongSensor)
    async def _conflict(request: Request, exc: Exception) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=409)

    @app.exception_handler(NotFound)
    async def _not_found(request: Request, exc: NotFound) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=404)

    @app.exception_handler(RecordingProblem)
    async def _recording(request: Request, exc: RecordingProblem) -> JSONResponse:
        return JSONResponse({"detail": exc.detail, "code": exc.code}, status_code=exc.status_code)


    @app.exception_handler(SQLAlchemyError)
    async def _db_error(request: Request, exc: SQLAlchemyError) -> JSONResponse:
        log.exception("store error")
        return JSONResponse(
            {"detail": f"the store is unavailable ({type(exc).__name__}). Try again; nothing was changed."}, status_code=503
        )

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = []
        for e in exc.errors():
            loc = ".".join(str(p) for p in e.get("loc", ()) if p != "body")
            errors.append(f"{loc}: {e.get('msg')}" if loc else str(e.get("msg")))
        return JSONResponse({"detail": "; ".join(errors) or "invalid request"}, status_code=422)


OPEN_ALWAYS = {"/health", "/auth/login"}


def publish_openapi(app: FastAPI, settings: Settings) -> None:
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
