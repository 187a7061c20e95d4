"""Asking a wearable which one it is: it blinks its light (or buzzes) for a few seconds, streaming or not."""

from __future__ import annotations

import asyncio
import contextlib
from typing import Any

from fastapi import APIRouter

from wearable_protocol.models import CANNOT_IDENTIFY, IDENTIFY_DEFAULT_S

from ... import schemas as M
from ...deps import R401, R404, R409, Operator, Svc, check_device_id, problem
from ...link import CommandError, LinkError
from ..views import reachable_device

router = APIRouter()

R502: dict[int | str, dict[str, Any]] = {502: {"model": M.Problem, "description": "the wearable could not be reached or refused"}}


@router.post("/devices/{device_id}/identify", response_model=M.IdentifyOut, responses={**R401, **R404, **R409, **R502},
             tags=["devices"])
async def identify_device(svc: Svc, device_id: str, operator: Operator, body: M.IdentifyIn | None = None) -> M.IdentifyOut:
    """Make the wearable blink its light (or buzz) for a few seconds, so the clinician can tell which one on the table
    it is. It may be streaming a session meanwhile: nothing else changes. 409 when its protocol has no such command."""
    check_device_id(device_id)
    dev = await reachable_device(svc, device_id)
    seconds = body.seconds if body else IDENTIFY_DEFAULT_S
    link = dev.get_link()
    was_connected = bool(getattr(link, "connected", False))
    try:
        if not was_connected:
            await link.connect()
        model = link.model  # the connected model: what its protocol can do
        if model is None or model.identify is None:
            raise problem(409, f"{model.label if model else 'this wearable'} {CANNOT_IDENTIFY}")
        await link.identify(seconds)
        seconds = model.identify_s or seconds  # a device with a pattern of its own blinks for as long as it does
    except CommandError as exc:
        raise problem(502, f"{dev.name or device_id} did not blink: {exc}") from None
    except LinkError as exc:
        raise problem(502, f"could not reach {dev.name or device_id} to make it blink: {exc}; check that it is on and "
                           "close to the receiver") from None
    finally:
        if not was_connected:
            # the link stays while it blinks (a Thingy's LED is put back over it), then goes unless a session took it
            task = asyncio.get_running_loop().create_task(_disconnect_later(svc, device_id, link, seconds))
            _LATER.add(task)
            task.add_done_callback(_LATER.discard)
    return M.IdentifyOut(device_id=device_id, seconds=seconds, how=model.identify,
                         message=f"{dev.name or device_id} {model.identify} for {seconds} s.")


_LATER: set[asyncio.Task[None]] = set()


async def _disconnect_later(svc: Any, device_id: str, link: Any, seconds: int) -> None:
    await asyncio.sleep(seconds + 0.5)
    if device_id in svc.active or getattr(link, "streaming", False):
        return
    with contextlib.suppress(Exception):
        await link.disconnect()
