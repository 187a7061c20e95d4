"""Which calibration was in force when a recording was made, and what the user should be warned of.

A calibration is in force from the moment it was accepted until the next one is. Scale factors and biases
change at every power-up and with temperature (the paper), so when the recording's power-up is known a
calibration of that same power-up is taken first; otherwise the latest one accepted by then. A calibration of
another sensor (a different serial or sensor model) is never taken. Past ``max_age_days`` (30 by default, as
imucal warns), across a power-up, or beyond ``max_temperature_change_c`` the answer warns.
"""

from __future__ import annotations

import asyncio
from dataclasses import replace
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Literal

import numpy as np
from pydantic import BaseModel, Field

from calib.apply.identity import IdentityCheckJson, SensorIdentity, WrongSensor, check_identity, same_power_up

from .config import CalibrationLimits
from .store import Store
from .store.records import CalibrationRecord, StoredPowerUp, StoredWatch

if TYPE_CHECKING:
    from calib.apply.temperature import TemperatureModel

DAY_S = 86400.0


class InForce(BaseModel):
    """When a calibration was asked for, why it is the one, how old it was then, and what to be warned of."""

    at: datetime = Field(description="the moment asked about (UTC)")
    age_days: float = Field(description="days from its acceptance to that moment (negative: accepted later in the same power-up)")
    chosen_by: Literal["same_power_up", "latest_before"] = Field(
        "latest_before", description="same_power_up: measured in the recording's power-up; latest_before: the latest accepted by then")
    identity_check: IdentityCheckJson | None = Field(
        None, description="sensor, power_up, temperature: same | different | unknown; temperature_change_c (calib.apply.identity)")
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


def calibration_identity(cal: CalibrationRecord) -> SensorIdentity:
    """What a calibration records of its sensor (its identity, completed by the columns every calibration has)."""
    return (cal.identity or SensorIdentity()).completed(SensorIdentity(device_id=cal.device_id, sensor_model=cal.sensor_model,
                                                                       firmware=cal.firmware))


def in_force(store: Store, device_id: str, at: datetime | None, limits: CalibrationLimits,
             recording: SensorIdentity | None = None) -> CalibrationInForce | None:
    """The calibration of ``device_id`` in force at ``at`` (now when None; a naive time is UTC) for a recording made
    as ``recording`` says (sensor, power-up, temperature; all optional). None when none had been accepted by then;
    raises WrongSensor when the only ones there are were measured on another sensor."""
    when = datetime.now(UTC) if at is None else (at if at.tzinfo is not None else at.replace(tzinfo=UTC)).astimezone(UTC)
    rec = replace(recording or SensorIdentity(), device_id=device_id)
    history = store.calibrations(device_id)  # newest first
    refusals = {c.id: check_identity(calibration_identity(c), rec).refusal for c in history}
    own = [c for c in history if refusals[c.id] is None]
    same = [c for c in own if same_power_up(calibration_identity(c), rec)]
    earlier = [c for c in own if c.accepted_at <= when]
    cal = same[0] if same else earlier[0] if earlier else None
    if cal is None:
        refused = next((refusals[c.id] for c in history if refusals[c.id] is not None and c.accepted_at <= when), None)
        if refused is not None:
            raise WrongSensor(refused)
        return None
    return judged(cal, when, limits, rec, "same_power_up" if same else "latest_before")


def judged(cal: CalibrationRecord, when: datetime, limits: CalibrationLimits, recording: SensorIdentity,
           chosen_by: Literal["same_power_up", "latest_before"] = "latest_before") -> CalibrationInForce:
    """``cal`` with its age at ``when``, its identity compared with the recording's, and the warnings."""
    age = age_days(cal.accepted_at, when)
    check = check_identity(calibration_identity(cal), recording, max_temperature_change_c=limits.max_temperature_change_c)
    warnings = []
    if age > limits.max_age_days:
        warnings.append(f"calibration #{cal.id} was accepted {age:.0f} days before this moment, more than the "
                        f"{limits.max_age_days:g} days allowed: calibrate the device again before using it for a study")
    warnings += check.warnings
    base = cal.model_dump(exclude={"in_force"})
    return CalibrationInForce(**base, in_force=InForce(at=when, age_days=age, chosen_by=chosen_by, identity_check=check.to_json(),
                                                       warnings=warnings))


class CalibrationDue(BaseModel):
    """Whether a device should be calibrated again before it is used for a study, and why."""

    due: bool
    reason: str = Field(description="in words: never calibrated, or how old its calibration is against the limit")


def calibration_due(current_accepted_at: datetime | None, max_age_days: float, now: datetime | None = None, *,
                    calibration_identity: SensorIdentity | None = None,
                    device_power_up: StoredPowerUp | None = None, latest_watch: StoredWatch | None = None) -> CalibrationDue:
    """Due when never calibrated, when the device was switched on again since its current calibration (the power-up
    it last reported, ``device_power_up``, is not the one in ``calibration_identity``), when the latest watch of that
    calibration on a study recording (``latest_watch``) found a parameter moved, or when it is older than
    ``max_age_days`` and no watch within that age confirmed it."""
    if current_accepted_at is None:
        return CalibrationDue(due=True, reason="never calibrated")
    now = now or datetime.now(UTC)
    age = age_days(current_accepted_at, now)
    if _powered_up_since(calibration_identity, device_power_up):
        return CalibrationDue(due=True, reason=f"switched on again since its calibration ({age:.0f} days old): a power-up changes "
                              "the gyroscope's scale factors and biases")
    if latest_watch is not None and latest_watch.verdict == "moved":
        moved = [p for p in latest_watch.parameters if p.verdict == "moved"]
        said = ", ".join(_moved_words(p.name, p.change, p.std) for p in moved)
        return CalibrationDue(due=True, reason=f"a study recording watched {_ago(latest_watch.at, now)} showed {said}")
    watched = _confirmed_days_ago(latest_watch, now)
    if age > max_age_days:
        if watched is not None and watched <= max_age_days:
            return CalibrationDue(due=False, reason=f"its calibration is {age:.0f} days old, and a study recording watched "
                                  f"{_days_ago(watched)} showed it holds")
        return CalibrationDue(due=True, reason=f"its calibration is {age:.0f} days old, more than the {max_age_days:g} days allowed")
    held = "; a study recording showed it holds" if watched is not None else ""
    return CalibrationDue(due=False, reason=f"its calibration is {age:.0f} days old, within the {max_age_days:g} days allowed{held}")


def _moved_words(name: str, change: float | None, std: float | None) -> str:
    """e.g. "k_x moved by -1.06 % ± 0.03 %", "b_z moved by -0.110 ± 0.004 deg/s"."""
    if change is None or std is None:
        return f"{name} moved"
    if name.startswith("k"):
        return f"{name} moved by {100 * change:+.2f} % ± {100 * std:.2f} %"
    return f"{name} moved by {change:+.3f} ± {std:.3f} deg/s"


def _ago(at: str | None, now: datetime) -> str:
    if at is None:
        return "lately"
    return _days_ago(age_days(datetime.fromisoformat(at), now))


def _days_ago(days: float) -> str:
    """"today", "1 day ago", "3 days ago"."""
    return "today" if days < 1 else f"{days:.0f} day{'' if round(days) == 1 else 's'} ago"


def _confirmed_days_ago(watch: StoredWatch | None, now: datetime) -> float | None:
    """How many days ago a watch confirmed the calibration (every parameter holds); None when none did."""
    if watch is None or watch.verdict != "holds" or watch.at is None:
        return None
    return age_days(datetime.fromisoformat(watch.at), now)


def _powered_up_since(calibration_identity: SensorIdentity | None, device_power_up: StoredPowerUp | None) -> bool:
    """Whether the power-up a device last reported is another than the one its calibration was measured in."""
    if not calibration_identity or not device_power_up:
        return False
    now = SensorIdentity.from_json({k: device_power_up.get(k) for k in ("boot_count", "booted_at")})
    return same_power_up(calibration_identity, now) is False


async def in_force_async(store: Store, device_id: str, at: datetime | None, limits: CalibrationLimits,
                         recording: SensorIdentity | None = None) -> CalibrationInForce | None:
    return await asyncio.to_thread(in_force, store, device_id, at, limits, recording)


def temperature_model(store: Store, cal: CalibrationRecord) -> TemperatureModel | None:
    """The device's scale factors and biases against temperature about ``cal``'s temperature (``model_of``, from what
    the store keeps of the device); None when nothing tells, or ``cal`` does not say its temperature."""
    return model_of(cal, store.watches(cal.device_id), store.calibrations(cal.device_id))


def model_of(cal: CalibrationRecord, watches: list[StoredWatch], calibrations: list[CalibrationRecord]) -> TemperatureModel | None:
    """k and b against temperature about ``cal``'s temperature, from every watch that had a temperature column and from
    the ``calibrations`` of ``cal``'s power-up made at different temperatures (calib.apply.temperature)."""
    from calib.apply.temperature import CalibrationAt, model_from_watches

    ident = cal.identity
    same_power_up = [
        CalibrationAt(float(c.identity.temperature_c), np.asarray(c.k), np.asarray(c.uncertainty.k), np.asarray(c.b),
                      np.asarray(c.uncertainty.b))
        for c in calibrations
        if ident is not None and ident.boot_count is not None and c.identity is not None and c.uncertainty is not None
        and c.identity.boot_count == ident.boot_count and c.identity.temperature_c is not None
    ]
    return model_from_watches((w.model_dump(mode="json") for w in watches), None if ident is None else ident.temperature_c,
                              same_power_up)
