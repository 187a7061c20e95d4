"""A sensor's scale factors and biases against its temperature, learned from watches of its calibrations on study
recordings (calib.watch) and from its calibrations of one power-up made at different temperatures, and applied
sample by sample:

    K(T) = diag(1 + s (T - T_cal)) K,    b(T) = b + c (T - T_cal),

T_cal the temperature the calibration was made at, c the bias's coefficient ((deg/s)/degC), s the scale factors'
(per degC; zero where nothing could tell). Each coefficient is the inverse-variance mean of what measured it: each
watch's, and the slope through the calibrations of the calibration's own power-up (a power-up moves k and b on its
own, so calibrations of different power-ups are never put on one line)."""

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
    calibrations: int = 0  # calibrations of one power-up at different temperatures it rests on too

    def to_json(self) -> dict[str, Any]:
        return {"temp_ref_c": self.temp_ref_c, "bias_tc_dps_per_c": self.bias_tc.tolist(),
                "bias_tc_std": self.bias_tc_std.tolist(), "scale_tc_per_c": self.scale_tc.tolist(),
                "scale_tc_std": None if self.scale_tc_std is None else self.scale_tc_std.tolist(), "watches": self.watches,
                "calibrations": self.calibrations}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> TemperatureModel:
        std = d.get("scale_tc_std")
        return cls(float(d["temp_ref_c"]), np.asarray(d["bias_tc_dps_per_c"], float), np.asarray(d["bias_tc_std"], float),
                   np.asarray(d["scale_tc_per_c"], float), None if std is None else np.asarray(std, float), int(d["watches"]),
                   int(d.get("calibrations") or 0))

    def rates(self, correction: Correction, gyro: np.ndarray, accel: np.ndarray | None, temp_c: np.ndarray | float) -> np.ndarray:
        """Calibrated rates (deg/s) of readings ``gyro`` at the sensor temperatures ``temp_c`` (per sample, or one
        for all; NaN samples get the calibration alone)."""
        return self.at_temperature(correction.apply(gyro, accel)[0], correction.b, temp_c)

    def at_temperature(self, rates: np.ndarray, b: np.ndarray, temp_c: np.ndarray | float) -> np.ndarray:
        """``rates`` a calibration (its bias ``b``) made of readings, taken to the sensor temperatures ``temp_c``."""
        dT = np.nan_to_num(np.asarray(temp_c, dtype=float) - self.temp_ref_c, nan=0.0)
        dT = np.broadcast_to(dT, (len(rates),))[:, None]
        return (rates - b) * (1.0 + self.scale_tc * dT) + b + self.bias_tc * dT


def _pooled(values: list[np.ndarray], stds: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    w = 1.0 / np.maximum(np.array(stds), 1e-12) ** 2
    return (w * np.array(values)).sum(axis=0) / w.sum(axis=0), 1.0 / np.sqrt(w.sum(axis=0))


@dataclass(frozen=True)
class CalibrationAt:
    """A calibration made at a known temperature (degC): its k and b with their stds."""

    temperature_c: float
    k: np.ndarray
    k_std: np.ndarray
    b: np.ndarray
    b_std: np.ndarray


MIN_SPREAD_C = 2.0  # calibrations of one power-up must be this far apart in temperature to give a slope


def _line(T: np.ndarray, y: np.ndarray, std: np.ndarray, at: float) -> tuple[float, float, float]:
    """The weighted least-squares line of y against T: its value at ``at``, its slope and the slope's std (scaled up
    when the points scatter more than their stds)."""
    w = 1.0 / np.maximum(std, 1e-12) ** 2
    X = np.column_stack([np.ones_like(T), T - at])
    info = X.T @ (X * w[:, None])
    beta = np.linalg.solve(info, X.T @ (w * y))
    cov = np.linalg.inv(info)
    dof = len(T) - 2
    chi2 = float(np.sum(w * (y - X @ beta) ** 2))
    if dof > 0 and chi2 > dof:
        cov = cov * chi2 / dof
    return float(beta[0]), float(beta[1]), float(np.sqrt(cov[1, 1]))


def _from_calibrations(cals: list[CalibrationAt], temp_ref_c: float
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """c, its std, s (relative to k at ``temp_ref_c``), its std, through calibrations of one power-up; None unless
    their temperatures spread enough."""
    T = np.array([c.temperature_c for c in cals])
    if len(cals) < 2 or np.ptp(T) < MIN_SPREAD_C:
        return None
    c = [_line(T, np.array([x.b[i] for x in cals]), np.array([x.b_std[i] for x in cals]), temp_ref_c)[1:] for i in range(3)]
    s = []
    for i in range(3):
        k_ref, slope, std = _line(T, np.array([x.k[i] for x in cals]), np.array([x.k_std[i] for x in cals]), temp_ref_c)
        s.append((slope / k_ref, std / k_ref))
    return np.array([v for v, _ in c]), np.array([e for _, e in c]), np.array([v for v, _ in s]), np.array([e for _, e in s])


def model_from_watches(reports: Iterable[dict[str, Any]], temp_ref_c: float | None,
                       calibrations: list[CalibrationAt] | None = None) -> TemperatureModel | None:
    """The model the watches' reports (``WatchReport.to_json`` form) and the ``calibrations`` of the calibration's own
    power-up measured, about the calibration's temperature ``temp_ref_c``; None when that is not known or neither
    told anything."""
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
    through = _from_calibrations(calibrations or [], float(temp_ref_c))
    if through is not None:
        bias.append(through[0])
        bias_std.append(through[1])
        scale.append(through[2])
        scale_std.append(through[3])
    if not bias:
        return None
    c, c_std = _pooled(bias, bias_std)
    s, s_std = _pooled(scale, scale_std) if scale else (np.zeros(3), None)
    return TemperatureModel(float(temp_ref_c), c, c_std, s, s_std, n, 0 if through is None else len(calibrations or []))


def corrected_at_temperature(rec: Recording, correction: Correction, model: TemperatureModel,
                             temperature_c: float | None = None) -> Recording:
    """``rec`` corrected with ``correction`` at the sensor's temperature: its temp column sample by sample, else
    ``temperature_c`` for all of it (the accelerometer as ``correction`` corrects it)."""
    temp = rec.temp if rec.temp is not None else temperature_c
    if temp is None:
        raise ValueError("a temperature model needs the recording's temperature: a temp column, or one for all of it")
    rates, accel = correction.apply(rec.gyro, rec.accel)
    return replace(rec, gyro=model.at_temperature(rates, correction.b, temp), accel=rec.accel if accel is None else accel)
