"""Signing operators in and out: POST /auth/login (throttled, audited), /auth/logout, GET /auth/me."""

from __future__ import annotations

import asyncio
import logging
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Request, Response
from fastapi.security import HTTPAuthorizationCredentials

from ... import schemas as M
from ...auth import AuthError, Throttled
from ...deps import (
    R401,
    Operator,
    Svc,
    bearer,
    problem,
)
from ...throttle import retry_after_header

log = logging.getLogger(__name__)
router = APIRouter()


@router.post("/auth/login", response_model=M.LoginOut, tags=["auth"], responses={
    401: {"model": M.Problem, "description": "unknown operator or wrong secret (audited)"},
    429: {"model": M.Problem, "description": "too many failed sign-ins for this operator or from this address (Retry-After)"},
})
async def login(svc: Svc, body: M.LoginIn, request: Request) -> dict[str, Any]:
    """Sign an operator in: name and secret in, bearer token out. After 5 failures for a name (20 from one
    address) each attempt waits 1, 2, 4, ... s (at most 5 min) after the last failure."""
    client = request.client.host if request.client else "unknown"
    try:
        token, expires = await svc.sign_ins.sign_in(body.operator, body.secret, client)
    except Throttled as exc:
        raise problem(429, str(exc), retry_after_header(exc.retry_after_s)) from None
    except AuthError as exc:
        raise problem(401, str(exc)) from None
    return {"token": token, "token_type": "bearer", "operator": body.operator, "expires_at": expires.isoformat()}


@router.post("/auth/logout", status_code=204, responses=R401, tags=["auth"])
async def logout(
    svc: Svc, request: Request, operator: Operator, creds: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]
) -> Response:
    """Revoke the token of this request."""
    if creds is not None:
        await asyncio.to_thread(svc.auth.sign_out, creds.credentials, operator)
    return Response(status_code=204)


@router.get("/auth/me", response_model=M.Me, responses=R401, tags=["auth"])
async def me(svc: Svc, operator: Operator) -> dict[str, str]:
    """The operator a token belongs to."""
    return {"operator": operator}
