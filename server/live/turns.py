"""A turn of a guided session that passed its checks, with its place in the session's recording."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class TurnRecord:
    """A turn that passed its checks, with its bounds in the session's recording."""

    axis: str
    start: int
    end: int
    start_s: float
    end_s: float
    angle_deg: np.ndarray  # integrated bias-compensated raw angle about x, y, z
    flags: tuple[str, ...]
    rest_before_s: float = 0.0  # how long the device rested before the turn
    gravity_change_deg: float | None = None  # gravity before vs after: 0 when put back in place

    def to_dict(self) -> dict[str, Any]:
        return {
            "axis": self.axis,
            "angle_deg": [round(float(a), 2) for a in self.angle_deg],
            "duration_s": round(self.end_s - self.start_s, 3),
            "start_s": round(self.start_s, 4),
            "end_s": round(self.end_s, 4),
            "rest_before_s": round(self.rest_before_s, 2),
            "gravity_change_deg": None if self.gravity_change_deg is None else round(self.gravity_change_deg, 1),
        }
