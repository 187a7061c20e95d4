"""Which sensor a calibration was measured on, in which power-up and at what temperature, and the rules for
applying it to a recording (docs/lifecycle.md, "Identity").

A calibration is never applied to another sensor: a device id or serial (chip id) that both sides name and that
differ refuse it; sensor models that differ only warn (a model name is a product's model number or its IMU
chip's, not an identity). Across a power-up (the paper, section 1: scale factors and biases change at every
power-up) or a temperature change beyond a limit (the zero-rate output moves 0.01-0.05 (deg/s)/degC in this
class of IMU) it still applies, with a warning. A power-up is the device's boot count when it keeps one, else
the time it started (read time minus uptime, to the second).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from datetime import UTC, datetime
from typing import Any, Literal

from typing_extensions import TypedDict  # on Python 3.11 pydantic reads a TypedDict only from typing_extensions

from calib.errors import GyrocalError

DEFAULT_MAX_TEMPERATURE_CHANGE_C = 3.0
BOOT_TIME_TOLERANCE_S = 5.0  # two reads of one power-up's start differ by the uptime's whole seconds and the read latency

Verdict = Literal["same", "different", "unknown"]


class IdentityError(GyrocalError, ValueError):
    """An identity field gyrocal cannot read; the message says which and why."""


class WrongSensor(GyrocalError):
    """A calibration was about to be applied to another sensor than the one it was measured on."""


class SensorIdentityJson(TypedDict):
    """A sensor identity's JSON form (booted_at in ISO 8601, UTC)."""

    device_id: str | None
    sensor_model: str | None
    serial: str | None
    firmware: str | None
    boot_count: int | None
    booted_at: str | None
    temperature_c: float | None


@dataclass(frozen=True)
class SensorIdentity:
    """A sensor and the power-up and temperature a calibration or a recording comes from; None: not known."""

    device_id: str | None = None
    sensor_model: str | None = None
    serial: str | None = None
    firmware: str | None = None
    boot_count: int | None = None
    booted_at: datetime | None = None  # UTC
    temperature_c: float | None = None

    def to_json(self) -> SensorIdentityJson:
        return SensorIdentityJson(device_id=self.device_id, sensor_model=self.sensor_model, serial=self.serial,
                                  firmware=self.firmware, boot_count=self.boot_count,
                                  booted_at=None if self.booted_at is None else self.booted_at.isoformat(),
                                  temperature_c=self.temperature_c)

    @classmethod
    def from_json(cls, d: Any) -> SensorIdentity:
        """From ``to_json``'s form (unknown keys ignored); raises IdentityError naming a field of the wrong kind."""
        if d is None:
            return cls()
        if not isinstance(d, dict):
            raise IdentityError(f"an identity is a JSON object of device_id, sensor_model, serial, ...; got {type(d).__name__}")
        out: dict[str, Any] = {}
        for name in ("device_id", "sensor_model", "serial", "firmware"):
            v = d.get(name)
            if v is not None and not isinstance(v, str):
                raise IdentityError(f"identity {name} must be text, got {v!r}")
            out[name] = v or None
        out["boot_count"] = _boot_count(d.get("boot_count"))
        out["booted_at"] = _time(d.get("booted_at"))
        out["temperature_c"] = _temperature(d.get("temperature_c"))
        return cls(**out)

    def completed(self, other: SensorIdentity) -> SensorIdentity:
        """This identity with the fields it does not know taken from ``other``."""
        return replace(self, **{f.name: getattr(other, f.name) for f in fields(self) if getattr(self, f.name) is None})

    @property
    def power_up_text(self) -> str:
        if self.boot_count is not None:
            return f"power-up #{self.boot_count}"
        if self.booted_at is not None:
            return f"the power-up of {self.booted_at.isoformat(timespec='seconds')}"
        return "an unknown power-up"


class IdentityCheckJson(TypedDict):
    """An identity check's JSON form."""

    sensor: Verdict
    power_up: Verdict
    temperature: Verdict
    temperature_change_c: float | None
    warnings: list[str]
    refusal: str | None


@dataclass(frozen=True)
class IdentityCheck:
    """The comparison of a calibration's identity with a recording's: what was checked, the warnings, and the
    reason it was refused (None: it may be applied)."""

    sensor: Verdict
    power_up: Verdict
    temperature: Verdict
    temperature_change_c: float | None
    warnings: tuple[str, ...]
    refusal: str | None

    def to_json(self) -> IdentityCheckJson:
        return IdentityCheckJson(sensor=self.sensor, power_up=self.power_up, temperature=self.temperature,
                                 temperature_change_c=self.temperature_change_c, warnings=list(self.warnings),
                                 refusal=self.refusal)

    def raise_if_refused(self) -> None:
        if self.refusal is not None:
            raise WrongSensor(self.refusal)


def _norm(text: str | None) -> str | None:
    return None if text is None else " ".join(text.split()).casefold() or None


def same_power_up(a: SensorIdentity, b: SensorIdentity) -> bool | None:
    """Whether two identities come from one power-up of the device; None when they cannot tell."""
    if a.boot_count is not None and b.boot_count is not None:
        return a.boot_count == b.boot_count
    if a.booted_at is not None and b.booted_at is not None:
        return abs((a.booted_at - b.booted_at).total_seconds()) <= BOOT_TIME_TOLERANCE_S
    return None


def check_identity(calibrated: SensorIdentity, recording: SensorIdentity, *,
                   max_temperature_change_c: float = DEFAULT_MAX_TEMPERATURE_CHANGE_C) -> IdentityCheck:
    """May a calibration measured as ``calibrated`` be applied to a recording made as ``recording``?"""
    differ = [f"{label} {getattr(calibrated, name)!r}, this recording {label} {getattr(recording, name)!r}"
              for name, label in (("device_id", "device"), ("serial", "serial"))
              if _norm(getattr(calibrated, name)) and _norm(getattr(recording, name))
              and _norm(getattr(calibrated, name)) != _norm(getattr(recording, name))]
    named = any(_norm(getattr(calibrated, n)) and _norm(getattr(recording, n)) for n in ("device_id", "serial"))
    sensor: Verdict = "different" if differ else "same" if named else "unknown"
    refusal = None
    if differ:
        refusal = ("this calibration was measured on another sensor (calibrated: " + "; ".join(differ) + "). A calibration "
                   "holds only for the sensor it was measured on: use that sensor's own calibration, or calibrate this one")
    warnings: list[str] = []
    model_a, model_b = _norm(calibrated.sensor_model), _norm(recording.sensor_model)
    if refusal is None and model_a and model_b and model_a != model_b:
        warnings.append(f"the calibration names the sensor {calibrated.sensor_model!r} and the recording {recording.sensor_model!r}: "
                        "a model name is not an identity (a product's model number or its IMU chip), so check they are the "
                        "same sensor; its serial would tell")
    same = same_power_up(calibrated, recording)
    power_up: Verdict = "unknown" if same is None else "same" if same else "different"
    if same is False:
        warnings.append(f"the calibration was measured in {calibrated.power_up_text} and the recording comes from "
                        f"{recording.power_up_text}: a MEMS gyroscope's scale factors and biases change at every power-up, "
                        "so calibrate again after switching the device on for the most accurate rates")
    change = None
    temperature: Verdict = "unknown"
    if calibrated.temperature_c is not None and recording.temperature_c is not None:
        change = round(recording.temperature_c - calibrated.temperature_c, 2)
        temperature = "same" if abs(change) <= max_temperature_change_c else "different"
        if temperature == "different":
            warnings.append(f"the recording is {abs(change):.1f} degC {'warmer' if change > 0 else 'colder'} than the calibration "
                            f"({calibrated.temperature_c:.1f} degC), beyond the {max_temperature_change_c:g} degC limit: the "
                            "biases move with temperature; calibrate at the temperature of the study")
    return IdentityCheck(sensor, power_up, temperature, change, tuple(warnings), refusal)


def _boot_count(v: Any) -> int | None:
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 0xFFFFFFFF:
        raise IdentityError(f"identity boot_count must be a whole number from 0 to 4294967295, got {v!r}")
    return v


def _time(v: Any) -> datetime | None:
    if v is None:
        return None
    if isinstance(v, datetime):
        t = v
    else:
        try:
            t = datetime.fromisoformat(str(v))
        except ValueError:
            raise IdentityError(f"identity booted_at must be an ISO 8601 time such as 2026-03-01T08:30:00+00:00, got {v!r}") from None
    return t.replace(tzinfo=UTC) if t.tzinfo is None else t.astimezone(UTC)


def _temperature(v: Any) -> float | None:
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not -60.0 <= v <= 150.0:
        raise IdentityError(f"identity temperature_c must be a temperature in degC (-60 to 150), got {v!r}")
    return float(v)
