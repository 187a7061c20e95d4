"""GET /audit: who did what, when, on which device (needs a token)."""

from __future__ import annotations

import asyncio
import logging
from typing import Annotated

from fastapi import APIRouter, Query

from ...deps import (
    R401,
    Operator,
    Svc,
)
from ...devices import DEVICE_ID_RE
from ...store.records import AuditEntry

log = logging.getLogger(__name__)
router = APIRouter()


@router.get("/audit", response_model=list[AuditEntry], responses=R401, tags=["service"])
async def audit(svc: Svc, 
    operator: Operator,
    device_id: Annotated[str | None, Query(max_length=128, pattern=DEVICE_ID_RE.pattern)] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 200,
) -> list[AuditEntry]:
    """The audit log, newest first: who did what, when, on which device (needs a token)."""
    return await asyncio.to_thread(svc.store.audit_log, device_id, limit)
