"""Whether a new calibration departs from its device's own history: a dropped or damaged sensor shows as scale
factors or biases that move further than power-ups and the new result's uncertainty explain.

For each parameter, the history's mean and spread (sample standard deviation over its calibrations, never below
what one power-up moves a low-cost MEMS gyroscope: 0.5 % of scale, 0.5 deg/s of bias) and the new value's own
standard deviation give z = (new - mean) / sqrt(spread^2 + std_new^2 + spread^2 / n). A parameter with |z| above
``DEPARTURE_Z`` departs. Two earlier calibrations at least are needed; with fewer there is no history to depart from.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, computed_field

from calib.stages.stage import AXES

DEPARTURE_Z = 4.0
MIN_HISTORY = 2
POWER_UP_SPREAD = {"k": 0.005, "b": 0.5}  # between power-ups, at least: scale (fraction), bias (deg/s)


class Departure(BaseModel):
    """One parameter of a new calibration that its device's history does not explain."""

    model_config = ConfigDict(frozen=True)
    name: Literal["k", "b"]
    axis: str
    value: float
    history_mean: float
    history_spread: float
    z: float = Field(description="standard deviations away from the history")
    n_history: int = Field(description="the device's earlier calibrations compared with")

    @computed_field  # type: ignore[prop-decorator]
    @property
    def text(self) -> str:
        """The departure in one sentence."""
        unit = "" if self.name == "k" else " °/s"
        return (f"{self.name}_{self.axis} = {self.value:.4f}{unit}, where this device's {self.n_history} earlier calibrations "
                f"gave {self.history_mean:.4f}{unit} ± {self.history_spread:.4f} ({abs(self.z):.0f} standard deviations away)")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form, with its sentence."""
        return self.model_dump(mode="json")


def departures(new: dict[str, Any], history: Sequence[dict[str, Any]]) -> list[Departure]:
    """The parameters of ``new`` (a result or calibration: k, b, uncertainty {k, b}) that depart from ``history``
    (the device's earlier calibrations, same form)."""
    if len(history) < MIN_HISTORY:
        return []
    out = []
    for name in ("k", "b"):
        past = np.array([h[name] for h in history], dtype=float)  # (n, 3)
        value = np.asarray(new[name], dtype=float)
        std_new = np.asarray(((new.get("uncertainty") or {}).get(name)) or np.zeros(3), dtype=float)
        floor = POWER_UP_SPREAD[name] * (np.abs(past.mean(axis=0)) if name == "k" else 1.0)
        spread = np.maximum(past.std(axis=0, ddof=1), floor)
        n = past.shape[0]
        z = (value - past.mean(axis=0)) / np.sqrt(spread**2 + std_new**2 + spread**2 / n)
        for i, axis in enumerate(AXES):
            if abs(z[i]) > DEPARTURE_Z:
                out.append(Departure(name=name, axis=axis, value=float(value[i]), history_mean=float(past[:, i].mean()),
                                     history_spread=float(spread[i]), z=float(z[i]), n_history=n))
    return out
