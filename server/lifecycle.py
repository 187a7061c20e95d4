"""Which calibration was in force when a recording was made, and what the user should be warned of.

A calibration is in force from the moment it was accepted until the next one is. Scale factors and biases
change at every power-up and with temperature (the paper), so a calibration used long after it was made
deserves a warning: past ``max_age_days`` (30 by default, as imucal warns) the answer says so.
"""

from __future__ import annotations

import asyncio
from datetime import UTC, datetime

from pydantic import BaseModel, Field

from .store import Store
from .store.records import CalibrationRecord

DAY_S = 86400.0


class InForce(BaseModel):
    """When a calibration was asked for, how old it was then, and what to be warned of."""

    at: datetime = Field(description="the moment asked about (UTC)")
    age_days: float = Field(description="days from its acceptance to that moment")
    warnings: list[str] = Field(default_factory=list, description="plain sentences: what makes it doubtful for that moment")


class CalibrationInForce(CalibrationRecord):
    """An accepted calibration, with why it is the one in force at the moment asked about."""

    in_force: InForce


def none_in_force(device_id: str, at: str | None) -> str:
    """The sentence for a device with no calibration in force at ``at`` (as the user wrote it; None: now)."""
    return f"device {device_id!r} has no accepted calibration {'yet' if at is None else f'by {at}'}"


def age_days(accepted_at: datetime, at: datetime) -> float:
    """Days from a calibration's acceptance to the moment ``at`` (both aware)."""
    return (at - accepted_at.astimezone(UTC)).total_seconds() / DAY_S


def in_force(store: Store, device_id: str, at: datetime | None, max_age_days: float) -> CalibrationInForce | None:
    """The calibration of ``device_id`` in force at ``at`` (now when None; a naive time is UTC), or None when
    none had been accepted by then."""
    when = datetime.now(UTC) if at is None else (at if at.tzinfo is not None else at.replace(tzinfo=UTC)).astimezone(UTC)
    cal = store.current_calibration(device_id, when)
    if cal is None:
        return None
    age = age_days(cal.accepted_at, when)
    warnings = []
    if age > max_age_days:
        warnings.append(f"calibration #{cal.id} was accepted {age:.0f} days before this moment, more than the "
                        f"{max_age_days:g} days allowed: calibrate the device again before using it for a study")
    return CalibrationInForce(**cal.model_dump(), in_force=InForce(at=when, age_days=age, warnings=warnings))


class CalibrationDue(BaseModel):
    """Whether a device should be calibrated again before it is used for a study, and why."""

    due: bool
    reason: str = Field(description="in words: never calibrated, or how old its calibration is against the limit")


def calibration_due(current_accepted_at: datetime | None, max_age_days: float, now: datetime | None = None) -> CalibrationDue:
    """Due when never calibrated, or when its current calibration is older than ``max_age_days``."""
    if current_accepted_at is None:
        return CalibrationDue(due=True, reason="never calibrated")
    age = age_days(current_accepted_at, now or datetime.now(UTC))
    if age > max_age_days:
        return CalibrationDue(due=True, reason=f"its calibration is {age:.0f} days old, more than the {max_age_days:g} days allowed")
    return CalibrationDue(due=False, reason=f"its calibration is {age:.0f} days old, within the {max_age_days:g} days allowed")


async def in_force_async(store: Store, device_id: str, at: datetime | None, max_age_days: float) -> CalibrationInForce | None:
    return await asyncio.to_thread(in_force, store, device_id, at, max_age_days)
