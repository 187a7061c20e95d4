"""What the API shows of devices and sessions: a device with its current calibration, a session's snapshot
(live from memory, or rebuilt from the store)."""

from __future__ import annotations

import asyncio
from typing import Any

from calib.json_safe import finite

from .. import schemas as M
from ..deps import problem
from ..devices import Device, model_facts
from ..lifecycle import calibration_due
from ..live.codes import END_STATES, known_reason
from ..live.kit_snapshot import stored_kit_snapshot
from ..live.snapshot import stored_snapshot
from ..live.snapshot_schema import RemoteGateway, SessionOut
from ..service import Service
from ..store import CalibrationRecord, StoredDevice, StoredSession


def held_facts(row: StoredDevice | None, current: CalibrationRecord | None) -> dict[str, Any]:
    """What the device last said it holds, and whether that is its current calibration (DeviceOut's held_* fields)."""
    held = None if row is None else row["held_calibration_id"]
    reported = None if row is None else row["held_reported_at"]
    state = None if reported is None else "none" if held is None else (
        "current" if current is not None and current.id == held else "other")
    return {"held_calibration_id": held, "held_reported_at": reported, "held_state": state}


async def reachable_device(svc: Service, device_id: str) -> Device:
    """The device to connect to: known to this service, or a BLE device known to the store; 404 / 409 otherwise."""
    dev = svc.devices.get(device_id)
    if dev is not None:
        return dev
    known = await asyncio.to_thread(svc.store.device, device_id)
    if known is None:
        raise problem(404, f"no device {device_id!r}; see GET /devices or scan with POST /devices/scan")
    if known.get("transport") == "ble" and svc.devices.ble:
        return svc.devices.add_ble_address(device_id)
    raise problem(409, f"device {device_id!r} is not reachable by this service (known from uploads only); scan for it first")


async def claim_device(svc: Service, device_id: str, holder: str | None, then: str, announce: bool = True) -> None:
    """Reserve a device for a session or verification (``holder``, its id) or for a write (``holder`` None); 409 saying
    what holds it otherwise. The claim here is made before the first await (of two requests at once exactly one gets
    the device); a gateway then takes the device's lease in the shared store, and gives the claim up when another
    gateway holds it. ``announce``: tell the fleet's pages now (a session does once its row is stored, so that the
    fleet view knows the lease holds a calibration)."""
    if device_id in svc.active:
        raise problem(409, f"device {device_id!r} is in a calibration session or verification ({svc.active[device_id]}); {then}")
    if device_id in svc.writing:
        raise problem(409, f"a calibration is being written to device {device_id!r}; {then}")
    if holder is None:
        svc.writing.add(device_id)
    else:
        svc.active[device_id] = holder
    if svc.gateway is not None:
        await _take_lease(svc, device_id, holder, then)
    if announce:
        svc.events.fleet_changed("claim", device_id)


async def _take_lease(svc: Service, device_id: str, holder: str | None, then: str) -> None:
    assert svc.gateway is not None
    try:
        lease = await svc.gateway.take(device_id, holder)
    except Exception:
        svc.release_device(device_id, holder)
        raise problem(503, f"the fleet's store could not be reached to take device {device_id!r}; try again") from None
    if lease.gateway != svc.gateway.name:
        svc.release_device(device_id, holder)
        raise problem(409, f"device {device_id!r} is in use on gateway {lease.gateway!r} ({lease.holder}) until "
                           f"{lease.expires_at.isoformat(timespec='seconds')} at the latest; {then}, or open it there")


async def calibration_or_404(svc: Service, calibration_id: int) -> CalibrationRecord:
    """The stored calibration of that id; 404 naming where the ids are listed otherwise."""
    cal = await asyncio.to_thread(svc.store.calibration, calibration_id)
    if cal is None:
        raise problem(404, f"no calibration #{calibration_id}; see GET /devices/{{id}}/calibrations")
    return cal


async def device_out(svc: Service, dev: Device | None, row: StoredDevice | None, detail: bool = False) -> M.DeviceOut:
    """A device as GET /devices shows it (``detail``: as GET /devices/{id} does): what this service knows of it live,
    what the store keeps, and its current calibration."""
    device_id = dev.id if dev is not None else row["id"] if row is not None else ""
    info = dev.info if dev is not None else {}
    current = await asyncio.to_thread(svc.store.current_calibration, device_id)
    watched = [] if current is None else await asyncio.to_thread(svc.store.watches, device_id, current.id, 1)
    recent = await asyncio.to_thread(svc.store.sessions, device_id, 10 if detail else 3)  # newest first
    # a calibration's result nobody decided on (a verification turn or a watch of a study recording asks no decision)
    judged = [r for r in recent if r["kind"] not in ("verify", "watch")]
    unsaved = None if svc.active.get(device_id) else next(
        (r for r in judged[:1] if r["state"] == "done" and r["passed"] and r["decision"] is None), None)
    power_up = None if row is None else row["power_up"]
    stored: dict[str, object] = dict(row) if row is not None else {}
    fields: dict[str, Any] = {
        "id": device_id,
        "name": (dev.name if dev else None) or stored.get("name"),
        "transport": dev.transport if dev else stored.get("transport"),
        "address": (dev.address if dev else None) or stored.get("address"),
        "connected": bool(dev and dev.connected),
        "available": dev is not None,
        "simulated": bool(dev and dev.simulated),
        "scenario": dev.scenario if dev else None,
        "sensor_model": info.get("sensor_model") or stored.get("sensor_model"),
        "firmware": info.get("firmware") or stored.get("firmware"),
        "serial": info.get("serial") or stored.get("serial"),
        "battery_pct": info.get("battery_pct"),
        **(dev.model_facts() if dev else model_facts(None)),
        "active_session": svc.active.get(device_id),
        "active_kit": next((k.id for k in svc.kits.values() if device_id in k.device_ids and not k.finished), None),
        "unsaved_session": None if unsaved is None else unsaved["id"],
        "unsaved_kit": None if unsaved is None else (unsaved.get("info") or {}).get("kit_id"),
        "current_calibration": current,
        **held_facts(row, current),
        "calibration_due": calibration_due(
            None if current is None else current.accepted_at, svc.settings.limits.max_age_days,
            calibration_identity=None if current is None else current.identity,
            device_power_up=power_up, latest_watch=watched[0] if watched else None,
        ),
        "power_up": power_up,
        "last_seen": stored.get("last_seen"),
    }
    if not detail:
        return M.DeviceOut.model_validate(fields)
    return M.DeviceDetail.model_validate({
        **fields,
        "simulated_truth": dev.simulated_truth if dev else None,
        "simulated_identifying": dev.simulated_identifying if dev else None,
        "info": finite(dict(info)),
        "recent_sessions": [M.SessionSummary.model_validate({**r, "reason_code": known_reason(r.get("reason_code"))})
                            for r in recent],
    })


async def session_snapshot(svc: Service, sid: str) -> SessionOut:
    if (kit := svc.kits.get(sid)) is not None:
        return kit.snapshot()
    live = svc.sessions.get(sid)
    if live is not None:
        if live.machine.finished and live.machine.decision is None and svc.gateway is not None:
            # decided on another gateway a moment ago: the store says so before that gateway's event arrives
            if (stored := await asyncio.to_thread(svc.session_as_stored, sid)) is not None:
                svc.decided_elsewhere(sid, stored)
        update: dict[str, object] = {"kind": "live", "operator": live.operator}
        if live.machine.finished:
            update |= {"stored": live.persisted, "store_error": live.persist_error}
        return live.machine.snapshot("state").model_copy(update=update)
    row = await asyncio.to_thread(svc.store.session, sid)
    if row is None:
        return await stored_kit(svc, sid, f"no session {sid}")
    if (gateway := runs_elsewhere(svc, row)) is not None:
        followed = svc.events.followed(sid)  # followed here: its latest relayed state, unless the store says it ended
        if followed is not None and (row["ended_at"] is None or followed.state in END_STATES):
            return followed
        return stored_snapshot(row).model_copy(update={"remote": await remote_gateway(svc, gateway)})
    return stored_snapshot(row)


REMOTE_END_WAIT_S = 3.0  # how long a decision waits for another gateway to write the end it has announced


async def decided_snapshot(svc: Service, sid: str) -> SessionOut:
    """The session's snapshot for a decision (accept, discard). A session that ran on another gateway is announced
    ended there a moment before that gateway has written its end to the store; a decision made here in that moment
    (from its event, or a page of that gateway) waits for the end to be written rather than refuse a finished session
    as still running."""
    snap = await session_snapshot(svc, sid)
    deadline = asyncio.get_running_loop().time() + REMOTE_END_WAIT_S
    while snap.remote is not None and snap.state not in END_STATES and asyncio.get_running_loop().time() < deadline:
        await asyncio.sleep(0.1)
        snap = await session_snapshot(svc, sid)
    return snap


async def stored_kit(svc: Service, kit_id: str, not_found: str) -> SessionOut:
    """A kit of an earlier run of the service, as the store keeps it; 404 saying ``not_found`` when it has no such kit."""
    stored = await asyncio.to_thread(svc.store.kit, kit_id)
    if stored is None:
        raise problem(404, not_found)
    return stored_kit_snapshot(*stored)


def runs_elsewhere(svc: Service, row: StoredSession) -> str | None:
    """The other gateway a stored session runs (or awaits its decision) on, whose events reach this one (None: it
    does not)."""
    gateway = row["gateway"]
    if (svc.events.shared and gateway and gateway != svc.gateway_name
            and row["decision"] is None and (row["ended_at"] is None or row["state"] == "done")):
        return gateway
    return None


async def remote_gateway(svc: Service, name: str) -> RemoteGateway:
    """Where a session of another gateway runs: its name and the URL its pages are at (None if not known)."""
    gateways = await asyncio.to_thread(svc.store.gateways)
    return RemoteGateway(gateway=name, url=next((g["url"] for g in gateways if g["name"] == name), None))
