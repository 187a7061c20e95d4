"""Signing operators in and out: POST /auth/login (throttled, audited), /auth/logout, GET /auth/me."""

from __future__ import annotations

import asyncio
import logging
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Request, Response
from fastapi.security import HTTPAuthorizationCredentials

from ... import schemas as M
from ...auth import API_OPERATOR, AuthError, PinRefused, Throttled
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
    401: {"model": M.Problem, "description": "unknown operator, wrong secret or wrong PIN (audited); 10 wrong PINs in a row "
                                             "switch the operator's PIN off"},
    403: {"model": M.Problem, "description": "a PIN from an address the service does not trust with PINs (--pin-from)"},
    429: {"model": M.Problem, "description": "too many failed sign-ins for this operator or from this address (Retry-After)"},
})
async def login(svc: Svc, body: M.LoginIn, request: Request) -> M.LoginOut:
    """Sign an operator in: name and secret (or PIN) in, bearer token out. After 5 failures for a name (3 with a
    PIN; 20 from one address) each attempt waits 1, 2, 4, ... s (at most 5 min) after the last failure."""
    client = request.client.host if request.client else "unknown"
    try:
        if body.pin is not None:
            token, expires = await svc.sign_ins.sign_in_pin(body.operator, body.pin, client)
        else:
            token, expires = await svc.sign_ins.sign_in(body.operator, body.secret or "", client)
    except Throttled as exc:
        raise problem(429, str(exc), retry_after_header(exc.retry_after_s)) from None
    except PinRefused as exc:
        raise problem(403, str(exc)) from None
    except AuthError as exc:
        raise problem(401, str(exc)) from None
    return M.LoginOut(token=token, token_type="bearer", operator=body.operator, expires_at=expires.isoformat())


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


NO_API_PIN: dict[int | str, dict[str, Any]] = {403: {"model": M.Problem, "description": "the API token's operator has no PIN"}}


@router.put("/auth/pin", status_code=204, tags=["auth"], responses={**R401, **NO_API_PIN})
async def set_pin(svc: Svc, operator: Operator, body: M.PinIn) -> Response:
    """Set the signed-in operator's PIN (4-8 digits), for signing in on the tablets the service trusts."""
    if operator == API_OPERATOR:
        raise problem(403, f'the "{API_OPERATOR}" operator signs in with its token only; sign in as a person to set a PIN')
    await asyncio.to_thread(svc.auth.set_pin, operator, body.pin)
    return Response(status_code=204)


@router.delete("/auth/pin", status_code=204, responses=R401, tags=["auth"])
async def remove_pin(svc: Svc, operator: Operator) -> Response:
    """Take the signed-in operator's PIN away."""
    if operator != API_OPERATOR:
        await asyncio.to_thread(svc.auth.set_pin, operator, None)
    return Response(status_code=204)
