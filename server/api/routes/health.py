"""GET /health: liveness, what the service runs on, and whether the store's history is intact."""

from __future__ import annotations

import asyncio
import logging
import time
from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, Query

from calib import __version__

from ... import schemas as M
from ...deps import (
    Svc,
)

log = logging.getLogger(__name__)
router = APIRouter()


@router.get("/health", response_model=M.Health, tags=["service"])
async def health(
    svc: Svc,
    verify: Annotated[bool, Query(description="verify the store's hash chains now (at most every few seconds) "
                                              "instead of reporting the last periodic check")] = False,
) -> M.Health:
    """Liveness, what the service runs on and whether the store's history is intact (never needs a token)."""
    integrity = svc.integrity
    if integrity is None or (verify and time.time() - datetime.fromisoformat(integrity.checked_at).timestamp() > 2.0):
        integrity = await svc.verify_store()
    clock = svc.clock.to_dict(svc.store.dialect)
    storage = svc.storage_warnings()
    return M.Health(
        status="tampered" if not integrity.ok else "degraded" if storage else "ok",
        integrity=integrity,
        version=__version__,
        store=svc.store.dialect,
        schema_version=await asyncio.to_thread(svc.store.schema_version),
        devices=len(svc.devices.devices),
        active_sessions=len(svc.active),
        auth_reads=svc.settings.auth_reads,
        clock=M.ClockOut.model_validate(clock),
        store_free_bytes=svc.store.free_bytes(),
        warnings=[*storage, *(w for w in [clock["warning"]] if w)],
    )
