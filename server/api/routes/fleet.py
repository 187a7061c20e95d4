"""GET /fleet: every gateway of the fleet sharing this store, and every wearable any of them has seen — where it
was last seen, whether a session holds it and on which gateway, its calibration status, and the link that opens
the wizard on the gateway that holds it (or saw it last). GET /fleet/events: the same view again each time the
fleet changes, on any gateway (server.fleet_events)."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from datetime import UTC, datetime
from typing import Literal

from fastapi import APIRouter
from fastapi.responses import StreamingResponse

from ... import schemas as M
from ...config import GatewaySettings
from ...deps import Reader, Svc
from ...gateway import WRITE_HOLDER
from ...lifecycle import calibration_due
from ...live.events import Event
from ...service import Service
from ...store import CalibrationRecord, Lease, StoredDevice, StoredWatch

router = APIRouter()


def _status(current: CalibrationRecord | None, row: StoredDevice | None, max_age_days: float,
            watched: list[StoredWatch]) -> M.CalibrationStatus:
    if current is None:
        return M.CalibrationStatus(status="never", reason="never calibrated")
    due = calibration_due(current.accepted_at, max_age_days, calibration_identity=current.identity,
                          device_power_up=None if row is None else row["power_up"], latest_watch=watched[0] if watched else None)
    return M.CalibrationStatus(status="due" if due.due else "current", reason=due.reason, calibration_id=current.id)


def _gateway_settings(svc: Service) -> GatewaySettings:
    """This gateway's settings; a service on its own judges the fleet's gateways by the defaults."""
    return svc.settings.gateway or GatewaySettings(name="")


def _activity(holder: str | None, sessions: set[str]) -> Literal["calibration", "verification", "write"] | None:
    """What holds a device: a calibration session (whose events any gateway's page can follow), a verification turn
    or a write of its calibration; None when nothing does."""
    if holder is None:
        return None
    if holder == WRITE_HOLDER:
        return "write"
    return "calibration" if holder in sessions else "verification"


def fleet_view(svc: Service) -> M.FleetOut:
    """The fleet as the store knows it (one consistent read of each table)."""
    store = svc.store
    gateways = store.gateways()
    urls = {g["name"]: g["url"] for g in gateways}
    silent = store.silent_gateways(_gateway_settings(svc).silent_after_s)  # on the database's clock, as leases are
    leases: dict[str, Lease] = {lease.device_id: lease for lease in store.leases()}
    seen: dict[str, list[M.SightingOut]] = {}
    for s in store.sightings():  # newest first for each device
        seen.setdefault(s["device_id"], []).append(M.SightingOut(gateway=s["gateway"], last_seen=s["last_seen"],
                                                                 rssi_dbm=s["rssi_dbm"]))
    rows = {r["id"]: r for r in store.devices()}
    current = store.current_calibrations()
    sessions = store.known_sessions(sorted({lease.holder for lease in leases.values()} | set(svc.active.values())))
    devices = []
    for device_id in sorted(set(rows) | set(seen)):
        row, cal = rows.get(device_id), current.get(device_id)
        lease = leases.get(device_id)
        sightings = seen.get(device_id, [])
        where = lease.gateway if lease else (sightings[0].gateway if sightings else svc.gateway_name)
        local_session = svc.active.get(device_id) if svc.gateway is None else None
        holder = lease.holder if lease else local_session
        base = urls.get(where) if where else None
        devices.append(M.FleetDevice(
            id=device_id,
            name=None if row is None else row["name"],
            gateway=where,
            last_seen=sightings[0].last_seen if sightings else None if row is None else row["last_seen"],
            seen_by=sightings,
            in_session=lease is not None or local_session is not None,
            session=holder,
            activity=_activity(holder, sessions),
            lease_expires_at=lease.expires_at.isoformat() if lease else None,
            calibration=_status(cal, row, svc.settings.limits.max_age_days, [] if cal is None else store.watches(device_id, cal.id, 1)),
            wizard_url=f"{base or ''}/#/place/{device_id}",
        ))
    return M.FleetOut(this_gateway=svc.gateway_name,
                      gateways=[M.GatewayOut(**g, alive=g["name"] not in silent, this=g["name"] == svc.gateway_name)
                                for g in gateways],
                      devices=devices, at=datetime.now(UTC).isoformat())


@router.get("/fleet", response_model=M.FleetOut, tags=["fleet"])
async def fleet(svc: Svc, _: Reader) -> M.FleetOut:
    """Every gateway sharing this store and every wearable they see: where, in a session or not, calibration status."""
    return await asyncio.to_thread(fleet_view, svc)


@router.get(
    "/fleet/events",
    responses={200: {"content": {"text/event-stream": {}}, "description": "Server-Sent Events: each the whole fleet view"}},
    response_class=StreamingResponse,
    tags=["fleet"],
)
async def fleet_events(svc: Svc, _: Reader) -> StreamingResponse:
    """The fleet view now, then again whenever the fleet changes on any gateway (a session started or ended, a
    calibration accepted, a wearable seen), and after a quiet heartbeat interval (a gateway falling silent)."""
    quiet_s = _gateway_settings(svc).heartbeat_s * 2

    async def stream() -> AsyncIterator[bytes]:
        yield b"retry: 1000\n\n"
        n = 1
        yield Event(n, "fleet", (await asyncio.to_thread(fleet_view, svc)).model_dump_json()).encode()
        async for _change in svc.events.fleet_changes(quiet_s):
            n += 1
            yield Event(n, "fleet", (await asyncio.to_thread(fleet_view, svc)).model_dump_json()).encode()

    return StreamingResponse(stream(), media_type="text/event-stream", headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})
