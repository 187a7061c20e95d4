"""The Stage type: one segment of a recording as the stage detector sees it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

StageKind = Literal["still", "turn", "motion"]
Axis = Literal["x", "y", "z"]
AXES: tuple[Axis, Axis, Axis] = ("x", "y", "z")
POSES = ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a")  # Ferraris' static poses: +x up, -x up, ...

# Quality flags a stage may carry.
FLAG_SATURATED = "saturated"  # some samples at the gyro's full scale
FLAG_COUNTER_GAP = "counter_gap"  # the sample counter skipped inside the stage


@dataclass(frozen=True)
class Stage:
    """A still segment, a full turn, or another motion; indices are samples [start, end)."""

    kind: StageKind
    start: int
    end: int
    start_s: float
    end_s: float
    axis: Axis | None = None  # dominant axis, turns only
    angle_deg: float | None = None  # signed bias-compensated integrated angle, turns only
    flags: tuple[str, ...] = field(default_factory=tuple)

    @property
    def n(self) -> int:
        return self.end - self.start

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s

    @classmethod
    def from_dict(cls, d: dict) -> Stage:
        """The Stage back from its ``to_dict()`` form."""
        return cls(
            d["kind"], int(d["start"]), int(d["end"]), float(d["start_s"]), float(d["end_s"]),
            d.get("axis"), d.get("angle_deg"), tuple(d.get("flags") or ()),
        )

    def to_dict(self) -> dict:
        """JSON-ready form: {kind, start_s, end_s, axis, angle_deg, start, end, flags}."""
        return {
            "kind": self.kind,
            "start_s": round(self.start_s, 6),
            "end_s": round(self.end_s, 6),
            "axis": self.axis,
            "angle_deg": None if self.angle_deg is None else round(self.angle_deg, 4),
            "start": self.start,
            "end": self.end,
            "flags": list(self.flags),
        }
