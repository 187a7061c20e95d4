"""Writing a calibration to the wearable that can hold one, reading it back, and recording what it holds."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import Any

from fastapi import APIRouter
from sqlalchemy.exc import SQLAlchemyError

from calib.apply.identity import check_identity
from wearable_protocol import HeldCalibration
from wearable_protocol.models import CANNOT_HOLD

from ... import schemas as M
from ...deps import R401, R404, R409, R503, Operator, Svc, check_device_id, problem
from ...devices import sensor_identity
from ...lifecycle import calibration_identity
from ...link import LinkError
from ...store import CalibrationRecord, StoreError
from ..views import claim_device, reachable_device

log = logging.getLogger(__name__)
router = APIRouter()

R502: dict[int | str, dict[str, Any]] = {
    502: {"model": M.Problem, "description": "the wearable could not be reached, refused the calibration or read back "
                                             "something else; what it holds was recorded"}
}


async def _chosen(svc: Svc, device_id: str, calibration_id: int | None) -> CalibrationRecord:
    if calibration_id is None:
        rec = await asyncio.to_thread(svc.store.current_calibration, device_id)
        if rec is None:
            raise problem(409, f"device {device_id!r} has no accepted calibration to write; calibrate it and accept the result first")
        return rec
    rec = await asyncio.to_thread(svc.store.calibration, calibration_id)
    if rec is None or rec.device_id != device_id:
        raise problem(404, f"calibration {calibration_id} is not one of device {device_id!r}'s; see GET /devices/{device_id}/calibrations")
    return rec


@router.post("/devices/{device_id}/calibration/write", response_model=M.WriteBackOut,
             responses={**R401, **R404, **R409, **R502, **R503}, tags=["calibrations"])
async def write_to_device(svc: Svc, device_id: str, operator: Operator, body: M.WriteBackIn | None = None) -> M.WriteBackOut:
    """Write a calibration (default: the current one) to the wearable with its id and CRC-32, read it back, verify
    it bit for bit and record that the device holds it. The wearable keeps streaming raw readings."""
    check_device_id(device_id)
    dev = await reachable_device(svc, device_id)
    await claim_device(svc, device_id, None, "write when that is done")
    try:
        rec = await _chosen(svc, device_id, body.calibration_id if body else None)
        held = HeldCalibration.from_parameters(rec.id, rec.K if rec.K is not None else rec.k, rec.b)
        back, warnings = await _write(svc, dev, held, rec)
        try:
            await asyncio.to_thread(svc.store.record_held, device_id, back.calibration_id, operator, True)
        except (StoreError, SQLAlchemyError) as exc:
            log.warning("write-back of %s to %s not recorded: %s", rec.id, device_id, exc)
            raise problem(503, f"the device holds calibration {rec.id} but the store could not record it "
                               f"({type(exc).__name__}); write again to record it") from None
        current = await asyncio.to_thread(svc.store.current_calibration, device_id)
    finally:
        svc.release_device(device_id, None)
    return M.WriteBackOut(device_id=device_id, calibration_id=back.calibration_id, verified=True,
                          held=M.HeldOut.model_validate(back.to_dict()),
                          held_state="current" if current is not None and current.id == back.calibration_id else "other",
                          warnings=warnings)


async def _write(svc: Svc, dev: Any, held: HeldCalibration, rec: CalibrationRecord) -> tuple[HeldCalibration, list[str]]:
    """Connect if needed, refuse another sensor's calibration, write and verify; whatever happens after connecting, what
    the device holds is recorded. The warnings: a calibration of another power-up or temperature."""
    link = dev.get_link()
    was_connected = bool(getattr(link, "connected", False))
    try:
        if not was_connected:
            await link.connect()
        if not link.holds_calibrations:
            dev.info["write_back"] = False
            label = dev.model_facts().get("model_label") or "this wearable"
            raise problem(409, f"{label} {CANNOT_HOLD}")
        check = check_identity(calibration_identity(rec), sensor_identity(dev.id, await link.read_info()),
                               max_temperature_change_c=svc.settings.limits.max_temperature_change_c)
        if check.refusal is not None:
            raise problem(409, f"calibration #{rec.id} was not written: {check.refusal}")
        try:
            return await link.write_calibration(held), list(check.warnings)
        except LinkError as exc:
            await dev.note_held(link, svc.store)
            raise problem(502, f"calibration {held.calibration_id} was not written: {exc}") from None
    except LinkError as exc:
        raise problem(502, f"could not reach the wearable to write the calibration: {exc}") from None
    finally:
        if not was_connected:
            with contextlib.suppress(Exception):
                await link.disconnect()
