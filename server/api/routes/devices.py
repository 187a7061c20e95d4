"""The wearables: list, scan, one device, its calibrations and its sessions."""

from __future__ import annotations

import asyncio
import logging
from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, Query

from ... import schemas as M
from ...deps import (
    R401,
    R404,
    R409,
    Operator,
    Reader,
    Svc,
    check_device_id,
    problem,
)
from ...lifecycle import CalibrationInForce, in_force_async, none_in_force
from ...live.snapshot import stored_snapshot
from ...live.snapshot_schema import SessionOut
from ..identity_query import RecordingIdentity
from ..views import device_out, session_snapshot

log = logging.getLogger(__name__)
router = APIRouter()


@router.get("/devices", response_model=list[M.DeviceOut], tags=["devices"])
async def list_devices(svc: Svc, _: Reader) -> list[M.DeviceOut]:
    """Known devices: the connectable ones (simulated, scanned) and those in the store's history."""
    rows = {r["id"]: r for r in await asyncio.to_thread(svc.store.devices)}
    ids = list(svc.devices.devices) + [i for i in rows if i not in svc.devices.devices]
    return [await device_out(svc, svc.devices.get(i), rows.get(i)) for i in ids]


@router.post("/devices/scan", response_model=M.ScanOut, responses=R401, tags=["devices"])
async def scan(
    svc: Svc, operator: Operator, timeout: Annotated[float, Query(gt=0, le=30, description="scan time, s")] = 5.0
) -> M.ScanOut:
    """Scan for wearables (BLE when the service runs with --ble); returns those found, each with its id."""
    try:
        found = await svc.devices.scan(timeout)
    except Exception as exc:
        raise problem(503, f"the Bluetooth scan failed ({exc}); check that Bluetooth is on") from None
    for dev in found:
        await asyncio.to_thread(svc.store.upsert_device, dev.id, name=dev.name, address=dev.address, transport=dev.transport)
    await asyncio.to_thread(svc.store.audit, operator, "devices.scan", None, None, {"found": [d.id for d in found]})
    rows = {r["id"]: r for r in await asyncio.to_thread(svc.store.devices)}
    return M.ScanOut(devices=[await device_out(svc, d, rows.get(d.id)) for d in found])


@router.get("/devices/{device_id}", response_model=M.DeviceDetail, responses=R404, tags=["devices"])
async def get_device(svc: Svc, device_id: str, _: Reader) -> M.DeviceOut:
    """One device: connection, current calibration, recent sessions; simulated ones show their truth."""
    check_device_id(device_id)
    dev = svc.devices.get(device_id)
    row = await asyncio.to_thread(svc.store.device, device_id)
    if dev is None and row is None:
        raise problem(404, f"no device {device_id!r}; see GET /devices or POST /devices/scan")
    return await device_out(svc, dev, row, detail=True)


@router.get("/devices/{device_id}/calibration", response_model=CalibrationInForce, responses={**R404, **R409}, tags=["calibrations"])
async def current_calibration(
    svc: Svc, device_id: str, _: Reader,
    recording: RecordingIdentity,
    at: Annotated[datetime | None, Query(description="ISO 8601 time (UTC unless it carries an offset); default now")] = None,
) -> CalibrationInForce:
    """The calibration in force: a calibration of the recording's power-up when ``boot_count`` (or ``booted_at``) names
    one, else the device's latest accepted one at or before ``at`` (default now); never one of another sensor (409).
    ``in_force`` says why it was taken, how old it was then, and warns past the service's age and temperature limits
    or across a power-up."""
    check_device_id(device_id)
    cur = await in_force_async(svc.store, device_id, at, svc.settings.limits, recording)
    if cur is None:
        raise problem(404, none_in_force(device_id, None if at is None else at.isoformat()))
    return cur


@router.get("/devices/{device_id}/calibrations", response_model=list[M.CalibrationRecord], responses=R404, tags=["calibrations"])
async def calibrations(svc: Svc, device_id: str, _: Reader) -> list[M.CalibrationRecord]:
    """Every accepted calibration of the device, newest first (nothing is ever overwritten)."""
    check_device_id(device_id)
    if svc.devices.get(device_id) is None and await asyncio.to_thread(svc.store.device, device_id) is None:
        raise problem(404, f"no device {device_id!r}")
    return await asyncio.to_thread(svc.store.calibrations, device_id)


@router.get("/devices/{device_id}/sessions", response_model=list[SessionOut], responses=R404, tags=["sessions"])
async def device_sessions(svc: Svc, device_id: str, _: Reader, limit: Annotated[int, Query(ge=1, le=500)] = 50) -> list[SessionOut]:
    """A device's sessions, newest first, whatever their outcome (kept for audit)."""
    check_device_id(device_id)
    rows = await asyncio.to_thread(svc.store.sessions, device_id, limit)
    out = []
    for r in rows:
        live = svc.sessions.get(r["id"])
        # a running session's row is written at its start and end: show its live state instead
        out.append(await session_snapshot(svc, r["id"]) if live is not None else stored_snapshot(r))
    return out
