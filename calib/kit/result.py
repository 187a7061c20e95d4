"""What a kit calibration returns: one ordinary ``CalibrationResult`` per wearable, and the kit's consistency."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calib.json_safe import finite
from calib.kit.clocks import ClockMap
from calib.kit.departure import Departure
from calib.kit.members import tilt_of
from calib.result import CalibrationResult


@dataclass(frozen=True, eq=False)
class Coherence:
    """How well a wearable followed the kit: the coupling's residual against its noise (deg/s, per axis) and its
    departure from the others' attitude."""

    residual_dps: np.ndarray
    noise_dps: np.ndarray
    departure: Departure

    @property
    def ratio(self) -> float:
        """The coupling's rms residual over the noise's: about 1 for a wearable that stayed put."""
        noise = float(np.mean(self.noise_dps**2))
        return float(np.sqrt(np.mean(self.residual_dps**2) / noise)) if noise > 0 else float("nan")

    def to_dict(self) -> dict[str, Any]:
        return {"residual_dps": [float(v) for v in self.residual_dps], "noise_dps": [float(v) for v in self.noise_dps],
                "residual_ratio": self.ratio, **self.departure.to_dict()}


@dataclass(eq=False)
class KitMember:
    """One wearable of the kit: its name, its calibration (None, with ``error``, when none could be made), its
    clock against the reference's, its mounting angle against the reference, how it followed the kit, whether it
    departed (then ``result`` is its calibration alone, which the kit's motion does not vouch for), and whether it turned
    with the kit at all (not: left out of the tray, or switched off; no result, ``error`` says so)."""

    name: str
    result: CalibrationResult | None
    clock: ClockMap
    mount_deg: float
    coherence: Coherence | None
    departed: bool = False
    error: str | None = None
    turned: bool = True

    def to_json(self) -> dict[str, Any]:
        return finite({
            "device_id": self.name,
            "result": None if self.result is None else self.result.to_json(),
            "clock": self.clock.to_dict(),
            "mount_deg": self.mount_deg,
            "consistency": None if self.coherence is None else self.coherence.to_dict(),
            "departed": self.departed,
            "turned": self.turned,
            "error": self.error,
        })


@dataclass(eq=False)
class KitResult:
    """Every wearable's calibration from one motion of the tray. ``reference`` names the wearable whose clock and
    frame the kit was solved in; ``mean`` is the calibration of the kit's mean recording in that frame."""

    members: list[KitMember]
    reference: str
    mean: CalibrationResult
    warnings: list[str] = field(default_factory=list)
    axes: dict[str, Any] | None = None  # the kit's axes model (calib.kit.axes.KitAxes.to_dict())

    @property
    def departed(self) -> list[str]:
        return [m.name for m in self.members if m.departed]

    @property
    def not_turned(self) -> list[str]:
        """The wearables that did not turn with the kit at all, left out of it."""
        return [m.name for m in self.members if not m.turned]

    def consistency(self) -> dict[str, Any]:
        """The kit's consistency: per wearable the coupling's residual and departure, and who departed."""
        return finite({
            "reference": self.reference,
            "devices": {m.name: None if m.coherence is None else m.coherence.to_dict() for m in self.members},
            "departed": self.departed,
            "not_turned": self.not_turned,
            "axes": None if self.axes is None else {**self.axes, "largest_tilt": self.largest_tilt()},
        })

    def largest_tilt(self) -> float | None:
        """The largest cross-axis term of any wearable's calibration (|K_ij| / K_jj above the diagonal); None when every
        wearable's K is diagonal."""
        tilts = [float(np.abs(tilt_of(m.result.K)).max()) for m in self.members if m.result is not None and m.result.K is not None]
        return max(tilts) if tilts else None

    def to_json(self) -> dict[str, Any]:
        """JSON-safe: ``devices`` (each wearable's result and consistency), ``kit`` (the consistency), ``warnings``."""
        return {"devices": [m.to_json() for m in self.members], "kit": self.consistency(),
                "warnings": list(self.warnings)}
