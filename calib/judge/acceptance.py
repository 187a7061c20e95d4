"""Whether a calibration may be used: the tolerances a recording's turns and its result must meet, and
each check of a result against them (what the service shows the operator before Accept).

A full turn reads 360/k degrees raw, so the turn-angle limits are a full turn for scale factors
k_max..k_min with a margin; the result limits are those of a working low-cost MEMS gyroscope.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from calib.json_safe import finite
from calib.result import CalibrationResult
from calib.stages.stage import AXES
from calib.units import FULL_TURN_DEG


@dataclass(frozen=True)
class Tolerances:
    """What a turn and a result must satisfy to pass (docs/service.md, "Tolerances")."""

    # raw integrated angle of a turn about the expected axis: a full turn reads 360/k, so these are a
    # full turn for scale factors k_max..k_min
    turn_angle_min_deg: float = 290.0  # k up to 1.24
    turn_angle_max_deg: float = 460.0  # k down to 0.78
    off_axis_max_fraction: float = 0.35  # rotation about the other two axes, as a fraction of the turn
    gravity_closure_max_deg: float = 15.0  # gravity before vs after a turn: the device is put back in place
    # ... and put back where it was: a hand puts a device back by eye 0.3-2 deg off; beyond 1 deg of tilt the turns'
    # calibrated closure (closure_max_deg below) cannot pass, so the turn is asked again at once
    placement_max_deg: float = 1.0
    k_min: float = 0.8  # scale factors outside 0.8..1.2 mean a faulty sensor or a protocol error
    k_max: float = 1.2
    b_max_dps: float = 10.0  # |bias| above this is outside every low-cost MEMS gyroscope's spec
    k_std_max: float = 0.01  # 1-sigma uncertainty of each scale factor
    b_std_max_dps: float = 0.1  # 1-sigma uncertainty of each bias (deg/s)
    # misclosure of each calibrated turn (closure estimator): a turn that was not a full one, or a device
    # not put back in place, leaves the other turns unable to close too
    closure_max_deg: float = 0.25


# a check that passes having used this much of its allowance is shown as close to its limit
NEAR_LIMIT_USED = 0.8


def _used(value: float, limit: float | tuple[float, float]) -> float:
    """How much of its allowance a value uses: 0 at the ideal (k = 1, everything else 0), 1 at the limit."""
    if isinstance(limit, tuple):
        lo, hi = float(limit[0]), float(limit[1])
        return (value - 1.0) / (hi - 1.0) if value >= 1.0 else (1.0 - value) / (1.0 - lo)
    return abs(value) / float(limit)


class Check(BaseModel):
    """One tolerance check of a result: the value, its limit (a bound on |value|, or the range [low, high] of a scale
    factor), whether it passed, the sentence that says so, how much of its allowance it used (None when the value
    is not finite) and whether a pass came close to the limit."""

    model_config = ConfigDict(frozen=True)
    name: Literal["k", "b", "k_std", "b_std", "closure"]
    axis: str | None
    value: float | None = Field(description="the value checked (null when it is not finite)")
    limit: float | tuple[float, float] = Field(description="a bound on |value|, or a scale factor's range [low, high]")
    ok: bool
    text: str
    used: float | None = Field(description="the share of the allowance the value uses: 0 ideal, 1 at the limit")
    near_limit: bool = Field(description=f"passed having used at least {NEAR_LIMIT_USED:g} of the allowance")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (the limit range as a list, a value that is not finite as null)."""
        return finite(self.model_dump(mode="json"))


def _check(name: str, axis: str | None, value: float, limit: float | tuple[float, float], ok: bool, text: str) -> Check:
    if not np.isfinite(value):  # a value that is not finite fails its check
        return Check(name=name, axis=axis, value=value, limit=limit, ok=False, text=text, used=None, near_limit=False)
    used = _used(value, limit)
    return Check(name=name, axis=axis, value=value, limit=limit, ok=ok, text=text, used=used,
                 near_limit=bool(ok and used >= NEAR_LIMIT_USED))


def evaluate(result: CalibrationResult, tol: Tolerances) -> list[Check]:
    """Each tolerance check of a result. A value that is not finite fails its check; an axis the recording did not
    turn about fails one check that says so (its k, and so its b, are not determined)."""
    checks: list[Check] = []
    undetermined = set(result.quality.get("undetermined_axes") or [])
    for i, a in enumerate(AXES):
        kv = float(result.k[i])
        if a in undetermined:
            checks.append(_check("k", a, kv, (tol.k_min, tol.k_max), False,
                                 f"k_{a} is not determined: no usable full turn about {a}; turn the device a full 360° "
                                 f"about {a} too"))
            continue
        checks.append(_check("k", a, kv, (tol.k_min, tol.k_max), tol.k_min <= kv <= tol.k_max,
                             f"k_{a} = {kv:.4f} (allowed {tol.k_min:g} to {tol.k_max:g})"))
    determined = [(i, a) for i, a in enumerate(AXES) if a not in undetermined]
    for i, a in determined:
        bv = float(result.b[i])
        checks.append(_check("b", a, bv, tol.b_max_dps, abs(bv) <= tol.b_max_dps,
                             f"b_{a} = {bv:.3f} °/s (allowed ±{tol.b_max_dps:g} °/s)"))
    if result.k_std is not None:
        for i, a in determined:
            v = float(result.k_std[i])
            checks.append(_check("k_std", a, v, tol.k_std_max, v <= tol.k_std_max,
                                 f"uncertainty of k_{a} = {v:.2g} (allowed {tol.k_std_max:g})"))
    if result.b_std is not None:
        for i, a in determined:
            v = float(result.b_std[i])
            checks.append(_check("b_std", a, v, tol.b_std_max_dps, v <= tol.b_std_max_dps,
                                 f"uncertainty of b_{a} = {v:.2g} °/s (allowed {tol.b_std_max_dps:g} °/s)"))
    # after calibration each full turn must bring the device back to the pose it was put back in
    for turn in result.residuals.get("turns") or []:
        if isinstance(turn, dict) and (miss := misclosure(turn)) is not None:
            v = float(miss)
            axis = turn.get("axis")
            checks.append(_check("closure", axis, v, tol.closure_max_deg, v <= tol.closure_max_deg,
                                 f"the calibrated turn about {axis} ends {v:.2f}° from the pose it was put back in "
                                 f"(allowed {tol.closure_max_deg:g}°)"))
    return checks


def turn_accuracy(result: CalibrationResult | dict[str, Any], in_force: dict[str, Any] | None = None) -> dict[str, Any] | None:
    """How far a full turn read from 360° before this calibration and after it, the worst turn of each:
    {"before_deg", "after_deg", "before_with", "before_calibration_id"}. "Before" is what the device used until now:
    its calibration in force (``in_force``, a stored calibration's JSON form: k, or K, and id), else the raw readings
    ("before_with": "calibration" or "raw"). A true full turn about axis a, which this calibration reads as 360°,
    reads 360 s_a / k_a through scale factors s (1 for the raw readings); "after" is how far each calibrated turn
    ends from where it began. None for a result without the closure estimator's turn rows."""
    doc = result.to_dict() if isinstance(result, CalibrationResult) else result
    rows = [t for t in (doc.get("residuals") or {}).get("turns") or []
            if isinstance(t, dict) and t.get("raw_angle_deg") is not None and misclosure(t) is not None]
    new = _scale_factors(doc)
    if not rows or new is None:
        return None
    old = _scale_factors(in_force)
    axes = {AXES.index(t["axis"]) for t in rows if t.get("axis") in AXES} or set(range(3))
    before = max(FULL_TURN_DEG * abs((1.0 if old is None else old[i]) / new[i] - 1.0) for i in axes)
    after = max(float(misclosure(t)) for t in rows)
    return {"before_deg": before, "after_deg": after, "before_with": "raw" if old is None else "calibration",
            "before_calibration_id": None if old is None or in_force is None else in_force.get("id")}


def misclosure(turn: dict[str, Any]) -> Any:
    """How far a calibrated turn ends from the pose the device was measured to be put back in (deg); a result from
    before the placement was modelled has only its closure."""
    value = turn.get("misclosure_norm_deg")
    return turn.get("closure_norm_deg") if value is None else value


def _scale_factors(calibration: dict[str, Any] | None) -> list[float] | None:
    """A stored calibration's scale factors about x, y, z (the diagonal of K), None when it has none usable."""
    if not calibration:
        return None
    full = calibration.get("K")
    k = [full[i][i] for i in range(3)] if full else calibration.get("k")
    try:
        values = [float(v) for v in k or []]
    except (TypeError, ValueError):
        return None
    return values if len(values) == 3 and all(np.isfinite(v) and v > 0 for v in values) else None
