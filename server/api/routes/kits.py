"""A kit: the wearables of one tray calibrated together in one guided session (server.live.kit_session)."""

from __future__ import annotations

import asyncio
import logging
import uuid

from fastapi import APIRouter, Response
from sqlalchemy.exc import SQLAlchemyError

from ... import schemas as M
from ...deps import R401, R404, R409, R503, Operator, Reader, Svc, check_device_id, check_session_id, problem
from ...live.codes import END_STATES
from ...live.kit_session import KitSession
from ...live.runner import LiveSession
from ...live.snapshot_schema import KitDeviceOut, SessionOut
from ...service import Service
from ...store import DecisionConflict, NotAcceptable, NotFound, StoreError, store_trouble
from ...store.calibrations import Acceptance
from ..views import claim_device, reachable_device, stored_kit
from .sessions import new_live

log = logging.getLogger(__name__)
router = APIRouter()
KEEP_FINISHED_KITS = 50


@router.post("/kits/calibrate", status_code=202, response_model=M.KitStarted,
             responses={**R401, **R404, **R409, **R503}, tags=["kits"])
async def calibrate_kit(svc: Svc, body: M.KitStart, response: Response, operator: Operator) -> M.KitStarted:
    """Start one guided session over every wearable of a tray, turned together (202). Each wearable is held by the kit
    until its own session ends (409 for a wearable another session holds: then none is taken). GET /sessions/{id}
    shows the kit: the step of the wearable furthest along, and ``devices``, each wearable's own state and result."""
    ids = list(body.devices)
    for device_id in ids:
        check_device_id(device_id)
    if len(set(ids)) != len(ids):
        raise problem(422, f"a wearable is named twice in the kit: {', '.join(ids)}; name each once")
    if (cannot_keep := svc.storage_problem()) is not None:
        raise problem(503, f"no calibration can be started: {cannot_keep}")
    devices = [await reachable_device(svc, device_id) for device_id in ids]
    kit_id = uuid.uuid4().hex
    sids = {device_id: uuid.uuid4().hex for device_id in ids}
    claimed: list[str] = []
    members: list[LiveSession] = []
    kit: KitSession[LiveSession] | None = None

    def member_ended(live: LiveSession) -> None:
        svc._session_ended(live)
        if kit is not None:
            kit.member_ended(live)

    try:
        for device_id in ids:
            await claim_device(svc, device_id, sids[device_id], "calibrate it once it is free, or leave it out of the kit",
                               announce=False)
            claimed.append(device_id)
        for dev in devices:
            members.append(await new_live(svc, dev, sids[dev.id], operator, None, body.max_attempts, member_ended))
        await asyncio.to_thread(svc.store.create_kit, kit_id, operator, sids, svc.gateway_name)
    except BaseException:
        for live in members:
            live.cancel("The kit could not be started.")
            svc.sessions.pop(live.id, None)
        for device_id in claimed:
            svc.release_device(device_id, sids[device_id])
        raise
    kit = KitSession(kit_id, members, svc.pool, svc.settings.compute_timeout_s, operator, on_end=lambda k: _forget_old(svc),
                     keep_outcome=lambda kid, out: svc.store.record_kit_outcome(kid, out.consistency, out.departed, out.refusal),
                     heading_prior_deg=svc.settings.heading_prior_deg)
    svc.kits[kit_id] = kit
    for live in members:
        live.start()
    kit.publish()
    url = f"/sessions/{kit_id}"
    response.headers["Location"] = url
    return M.KitStarted(session_id=kit_id, state=kit.snapshot().state, url=url,
                        devices=[M.KitMemberStarted(device_id=i, session_id=sids[i]) for i in ids])


@router.get("/kits/{kit_id}", response_model=SessionOut, responses=R404, tags=["kits"])
async def get_kit(svc: Svc, kit_id: str, _: Reader) -> SessionOut:
    """A kit session, as GET /sessions/{id} shows it (a kit of an earlier run of the service, as the store keeps it)."""
    return await _kit_snapshot(svc, kit_id)


@router.post("/kits/{kit_id}/cancel", response_model=SessionOut, responses={**R401, **R404, **R409}, tags=["kits"])
async def cancel_kit(svc: Svc, kit_id: str, operator: Operator) -> SessionOut:
    """Cancel every wearable's session of the kit that still runs."""
    kit = svc.kits.get(kit_id)
    if kit is None:
        snap = await _kit_snapshot(svc, kit_id)  # 404 if unknown
        if snap.state not in END_STATES:
            raise problem(409, "this kit runs on another gateway, where its wearables are: cancel it there")
        raise problem(409, "the kit's sessions have ended already; nothing to cancel")
    if not kit.cancel():
        raise problem(409, "the kit's sessions have ended already; nothing to cancel")
    await asyncio.to_thread(svc.store.audit, operator, "kit.cancel", None, kit_id)
    for live in kit.members:
        await live.wait()
    return kit.snapshot()


@router.post("/kits/{kit_id}/accept", response_model=M.KitAcceptOut, responses={**R401, **R404, **R409, **R503}, tags=["kits"])
async def accept_kit(svc: Svc, kit_id: str, operator: Operator) -> M.KitAcceptOut:
    """Make the result of every wearable of the kit that passed its device's calibration, all in one transaction (all or
    none, one audit entry per device). The others are named with the reason; each can be calibrated again alone. A kit
    of an earlier run of the service is accepted from what the store kept of it."""
    kit = svc.kits.get(kit_id)
    snap = await _kit_snapshot(svc, kit_id)
    if snap.state not in END_STATES:
        raise problem(409, "the kit is still being calibrated: accept it once every wearable's session has ended")
    running = {live.device.id: live for live in (kit.members if kit is not None else [])}
    for live in running.values():  # each one's outcome written first
        await live.wait()
    passed = [d for d in snap.devices if d.state == "done" and d.passed and d.decision is None and not d.departed]
    not_accepted = {d.device_id: _why_not(d) for d in snap.devices if d not in passed}
    if not passed:
        decided = [f"{d.device_id} {d.decision}" for d in snap.devices if d.decision]
        if decided:
            raise problem(409, f"the kit was decided already ({', '.join(decided)}): nothing was changed")
        raise problem(409, "no wearable of the kit passed: " + "; ".join(f"{k}: {v}" for k, v in not_accepted.items()))
    accepts = [_acceptance(running[d.device_id]) if d.device_id in running else Acceptance(d.session_id) for d in passed]
    try:
        records = await asyncio.to_thread(svc.store.accept_many, accepts, operator)
    except DecisionConflict as exc:  # decided meanwhile (another operator's accept of the kit, or of that wearable alone)
        device = next((d.device_id for d in passed if d.session_id == exc.session_id), exc.session_id)
        raise problem(409, f"{device}'s calibration was {exc.decided}, so none of the kit's was stored by this request: "
                           "reload the kit to see what was decided") from None
    except (NotAcceptable, NotFound):
        raise  # 409 / 404 with the store's own sentence (server.main)
    except (StoreError, SQLAlchemyError) as exc:
        log.warning("accept of kit %s failed: %s", kit_id, exc)
        raise problem(503, f"the kit's calibrations could not be stored: {store_trouble(exc)}. No wearable's calibration "
                           "changed; try accepting again.") from None
    for d, rec in zip(passed, records, strict=True):
        if (member := running.get(d.device_id)) is not None:
            member.machine.decide("accepted", rec.id)
            member.broadcaster.close()
        svc.events.fleet_changed("calibration", rec.device_id)
        svc.events.decided(d.session_id)
    if kit is not None:
        kit.close_stream()
    return M.KitAcceptOut(session_id=kit_id, calibrations=records, not_accepted=not_accepted)


def _acceptance(live: LiveSession) -> Acceptance:
    return Acceptance(live.id, live.machine.result, end=live.session_end(), identity=live.identity,
                      sensor_model=live.device.info.get("sensor_model"), firmware=live.device.info.get("firmware"),
                      recording_csv=live.csv_bytes, n_samples=live.csv_samples)


def _why_not(d: KitDeviceOut) -> str:
    if d.departed:
        return d.reason or "it came apart from the kit"
    if d.decision:
        return f"decided already ({d.decision})"
    if d.state == "done":
        return "its result is outside the tolerances"
    return d.reason or f"its session ended {d.state}"


async def _kit_snapshot(svc: Service, kit_id: str) -> SessionOut:
    """The kit running here, or as the store keeps it (404: no kit session has that id)."""
    check_session_id(kit_id)
    if (kit := svc.kits.get(kit_id)) is not None:
        return kit.snapshot()
    return await stored_kit(svc, kit_id, f"no kit session {kit_id}")


def _forget_old(svc: Service) -> None:
    finished = [k for k in svc.kits.values() if k.finished]
    for old in finished[: max(0, len(finished) - KEEP_FINISHED_KITS)]:
        svc.kits.pop(old.id, None)
        old.close_stream()
