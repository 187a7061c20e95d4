"""GET /fleet: every gateway of the fleet sharing this store, and every wearable any of them has seen — where it
was last seen, whether a session holds it and on which gateway, its calibration status, and the link that opens
the wizard on the gateway that holds it (or saw it last)."""

from __future__ import annotations

import asyncio
from datetime import UTC, datetime, timedelta
from typing import Any

from fastapi import APIRouter

from ...config import GatewaySettings
from ...deps import Reader, Svc
from ...lifecycle import calibration_due
from ...service import Service
from ...store import Lease

router = APIRouter()


def _status(current: Any, row: dict[str, Any], max_age_days: float) -> dict[str, Any]:
    if current is None:
        return {"status": "never", "reason": "never calibrated", "calibration_id": None}
    identity = None if current.identity is None else current.identity.to_json()
    due = calibration_due(current.accepted_at, max_age_days, calibration_identity=identity,
                          device_power_up=row.get("power_up"))
    return {"status": "due" if due.due else "current", "reason": due.reason, "calibration_id": current.id}


def fleet_view(svc: Service) -> dict[str, Any]:
    """The fleet as the store knows it (one consistent read of each table)."""
    store = svc.store
    now = datetime.now(UTC)
    gateways = store.gateways()
    urls = {g["name"]: g["url"] for g in gateways}
    silent_after_s = (svc.settings.gateway or GatewaySettings(name="")).silent_after_s  # a service on its own: the defaults
    for g in gateways:
        g["alive"] = datetime.fromisoformat(g["heartbeat_at"]) > now - timedelta(seconds=silent_after_s)
        g["this"] = g["name"] == svc.gateway_name
    leases: dict[str, Lease] = {lease.device_id: lease for lease in store.leases() if lease.expires_at > now}
    seen: dict[str, list[dict[str, Any]]] = {}
    for s in store.sightings():  # newest first for each device
        seen.setdefault(s["device_id"], []).append({k: s[k] for k in ("gateway", "last_seen", "rssi_dbm")})
    rows = {r["id"]: r for r in store.devices()}
    devices = []
    for device_id in sorted(set(rows) | set(seen)):
        row = rows.get(device_id, {})
        lease = leases.get(device_id)
        sightings = seen.get(device_id, [])
        where = lease.gateway if lease else (sightings[0]["gateway"] if sightings else svc.gateway_name)
        local_session = svc.active.get(device_id) if svc.gateway is None else None
        base = urls.get(where) if where else None
        devices.append({
            "id": device_id,
            "name": row.get("name"),
            "gateway": where,
            "last_seen": sightings[0]["last_seen"] if sightings else row.get("last_seen"),
            "seen_by": sightings,
            "in_session": lease is not None or local_session is not None,
            "session": lease.holder if lease else local_session,
            "lease_expires_at": lease.expires_at.isoformat() if lease else None,
            "calibration": _status(store.current_calibration(device_id), row, svc.settings.limits.max_age_days),
            "wizard_url": f"{base or ''}/#/place/{device_id}",
        })
    return {"this_gateway": svc.gateway_name, "gateways": gateways, "devices": devices, "at": now.isoformat()}


@router.get("/fleet", tags=["fleet"])
async def fleet(svc: Svc, _: Reader) -> dict[str, Any]:
    """Every gateway sharing this store and every wearable they see: where, in a session or not, calibration status."""
    return await asyncio.to_thread(fleet_view, svc)
