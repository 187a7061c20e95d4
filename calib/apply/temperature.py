"""A sensor's scale factors and biases against its temperature, learned from watches of its calibrations on study
recordings (calib.watch), and applied sample by sample:

    K(T) = diag(1 + s (T - T_cal)) K,    b(T) = b + c (T - T_cal),

T_cal the temperature the calibration was made at, c the bias's coefficient ((deg/s)/degC), s the scale factors'
(per degC; zero where no watch could tell). Each coefficient is the inverse-variance mean of the watches' that
measured it."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from calib.apply.correction import Correction
from calib.recording import Recording


@dataclass(frozen=True)
class TemperatureModel:
    """c and s (with their stds) about ``temp_ref_c``, from ``watches`` watches."""

    temp_ref_c: float
    bias_tc: np.ndarray
    bias_tc_std: np.ndarray
    scale_tc: np.ndarray
    scale_tc_std: np.ndarray | None
    watches: int

    def to_json(self) -> dict[str, Any]:
        return {"temp_ref_c": self.temp_ref_c, "bias_tc_dps_per_c": self.bias_tc.tolist(),
                "bias_tc_std": self.bias_tc_std.tolist(), "scale_tc_per_c": self.scale_tc.tolist(),
                "scale_tc_std": None if self.scale_tc_std is None else self.scale_tc_std.tolist(), "watches": self.watches}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> TemperatureModel:
        std = d.get("scale_tc_std")
        return cls(float(d["temp_ref_c"]), np.asarray(d["bias_tc_dps_per_c"], float), np.asarray(d["bias_tc_std"], float),
                   np.asarray(d["scale_tc_per_c"], float), None if std is None else np.asarray(std, float), int(d["watches"]))

    def rates(self, correction: Correction, gyro: np.ndarray, accel: np.ndarray | None, temp_c: np.ndarray | float) -> np.ndarray:
        """Calibrated rates (deg/s) of readings ``gyro`` at the sensor temperatures ``temp_c`` (per sample, or one
        for all; NaN samples get the calibration alone)."""
        base, _ = correction.apply(gyro, accel)
        dT = np.nan_to_num(np.asarray(temp_c, dtype=float) - self.temp_ref_c, nan=0.0)
        dT = np.broadcast_to(dT, (len(base),))[:, None]
        return (base - correction.b) * (1.0 + self.scale_tc * dT) + correction.b + self.bias_tc * dT


def _pooled(values: list[np.ndarray], stds: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    w = 1.0 / np.maximum(np.array(stds), 1e-12) ** 2
    return (w * np.array(values)).sum(axis=0) / w.sum(axis=0), 1.0 / np.sqrt(w.sum(axis=0))


def model_from_watches(reports: Iterable[dict[str, Any]], temp_ref_c: float | None) -> TemperatureModel | None:
    """The model the watches' reports (``WatchReport.to_json`` form) measured about the calibration's temperature
    ``temp_ref_c``; None when it is not known or no watch had a temperature column."""
    if temp_ref_c is None:
        return None
    bias, bias_std, scale, scale_std, n = [], [], [], [], 0
    for r in reports:
        b = r.get("bias") or {}
        if b.get("temperature_coeff_dps_per_c") is None or b.get("temperature_coeff_std") is None:
            continue
        n += 1
        bias.append(np.asarray(b["temperature_coeff_dps_per_c"], float))
        bias_std.append(np.asarray(b["temperature_coeff_std"], float))
        sc = r.get("scale") or {}
        if sc.get("temperature_coeff_per_c") is not None and sc.get("temperature_coeff_std") is not None:
            scale.append(np.asarray(sc["temperature_coeff_per_c"], float))
            scale_std.append(np.asarray(sc["temperature_coeff_std"], float))
    if not n:
        return None
    c, c_std = _pooled(bias, bias_std)
    s, s_std = _pooled(scale, scale_std) if scale else (np.zeros(3), None)
    return TemperatureModel(float(temp_ref_c), c, c_std, s, s_std, n)


def corrected_at_temperature(rec: Recording, correction: Correction, model: TemperatureModel,
                             temperature_c: float | None = None) -> Recording:
    """``rec`` corrected with ``correction`` at the sensor's temperature: its temp column sample by sample, else
    ``temperature_c`` for all of it (the accelerometer as ``correction`` corrects it)."""
    temp = rec.temp if rec.temp is not None else temperature_c
    if temp is None:
        raise ValueError("a temperature model needs the recording's temperature: a temp column, or one for all of it")
    _, accel = correction.apply(rec.gyro, rec.accel)
    return replace(rec, gyro=model.rates(correction, rec.gyro, rec.accel, temp), accel=rec.accel if accel is None else accel)
