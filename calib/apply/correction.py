"""A calibration to apply to recordings: read from gyrocal's own JSON or from an imucal calibration file, applied
to raw readings, and written back in either form.

gyrocal's model is g = K (m - G a) + b (rates in deg/s, b in deg/s of true rate, G in (deg/s)/g, a in g) and,
when the accelerometer was calibrated, a = T S (r - o) (``calib.estimators.accel``). imucal's Ferraris calibration
(imucal 2.x, ``FerrarisCalibrationInfo``) calibrates

    acc = R_a^-1 K_a^-1 (r - b_a),        gyr = R_g^-1 K_g^-1 (m - K_ga acc - b_g)

so K = R_g^-1 K_g^-1, b = -K b_g and G = K_ga, and the accelerometer's a = A (r - o) with A = R_a^-1 K_a^-1,
o = b_a (A = T S for a model gyrocal fitted), each converted from imucal's units (its ``from_acc_unit`` for the
readings it takes, ``acc_unit`` for what it gives: g or m/s^2) to g. Written for
imucal: K_g = K^-1 with R_g = I (K_g = diag(1/k) for a diagonal K), b_g = -K^-1 b, K_ga = G, K_a = A^-1 with
R_a = I, b_a = o, all in the units gyrocal's readings have (deg/s and g).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from calib.apply.identity import IdentityError, SensorIdentity
from calib.errors import GyrocalError
from calib.estimators.accel import AccelCalibration
from calib.recording import Recording
from calib.result import CalibrationResult
from calib.units import STANDARD_GRAVITY

IMUCAL_FORMAT = "2.0.0"  # imucal's calibration-file format version this module reads and writes
IMUCAL_ACC_UNITS = {"g": 1.0, "m/s^2": STANDARD_GRAVITY}


class CorrectionFileError(GyrocalError, ValueError):
    """A calibration file gyrocal cannot use; the message says what is wrong with it."""


@dataclass(frozen=True)
class Correction:
    """What applying a calibration needs: the gyroscope's K, b (and G), and the accelerometer's model if calibrated."""

    K: np.ndarray  # (3, 3)
    b: np.ndarray  # (3,) deg/s of true rate
    G: np.ndarray | None = None  # (3, 3) (deg/s)/g
    A: np.ndarray | None = None  # (3, 3) the accelerometer's a = A (r - o): T S for gyrocal's model; None: not calibrated
    o: np.ndarray | None = None  # (3,) its offsets, g
    source: str = "gyrocal"  # gyrocal | imucal: the file it was read from
    identity: SensorIdentity | None = None  # the sensor, power-up and temperature it was measured at, when the file says

    @classmethod
    def from_result(cls, result: CalibrationResult) -> Correction:
        """The correction a calibration result defines (with its accelerometer's, when it calibrated one)."""
        A, o = _accel(result.quality.get("accelerometer"))
        return cls(K=result.matrix.copy(), b=np.asarray(result.b, float).copy(), G=None if result.G is None else result.G.copy(), A=A, o=o)

    @classmethod
    def from_json(cls, d: Any) -> Correction:
        """gyrocal's calibration JSON (at least ``{"k": [...], "b": [...]}``; a stored calibration or result works) or
        an imucal calibration file's JSON (``"cal_type": "Ferraris"``)."""
        if not isinstance(d, dict):
            raise CorrectionFileError("a calibration file is a JSON object: gyrocal's ({\"k\": [...], \"b\": [...]}) or imucal's")
        if "cal_type" in d:
            return cls._from_imucal(d)
        try:
            k = _vector(d.get("k"), "k")
            b = _vector(d.get("b"), "b")
            K = np.diag(k) if d.get("K") is None else _matrix(d["K"], "K")
            G = None if d.get("G") is None else _matrix(d["G"], "G")
            A, o = _accel(d.get("accelerometer") or (d.get("quality") or {}).get("accelerometer"))
            identity = None if d.get("identity") is None else SensorIdentity.from_json(d["identity"])
        except IdentityError as exc:
            raise CorrectionFileError(f"the calibration's identity is unreadable: {exc}") from None
        except (KeyError, TypeError, ValueError) as exc:
            raise CorrectionFileError(f"not a gyrocal calibration: {exc}; it needs \"k\" and \"b\", three numbers each") from None
        if abs(np.linalg.det(K)) < 1e-9:
            raise CorrectionFileError("this K cannot be a calibration (it is singular): check the file's \"k\" (or \"K\")")
        return cls(K=K, b=b, G=G, A=A, o=o, identity=identity)

    @classmethod
    def _from_imucal(cls, d: dict[str, Any]) -> Correction:
        if d.get("cal_type") != "Ferraris":
            raise CorrectionFileError(f"imucal calibration type {d.get('cal_type')!r}: gyrocal reads imucal's Ferraris calibrations")
        # imucal's from_*_unit: the raw readings it expects; *_unit: what it gives (None: as gyrocal's, g and deg/s)
        units = {"input": d.get("from_acc_unit") or "g", "output": d.get("acc_unit") or "g"}
        for which, unit in units.items():
            if unit not in IMUCAL_ACC_UNITS:
                raise CorrectionFileError(f"this imucal calibration's {which} acceleration is in {unit!r}; gyrocal's readings are "
                                          "in g, so it applies calibrations that take and give g or m/s^2 (recalibrate from "
                                          "readings in physical units)")
        for key in ("from_gyr_unit", "gyr_unit"):
            if (d.get(key) or "deg/s") != "deg/s":
                raise CorrectionFileError(f"this imucal calibration's {key} is {d.get(key)!r}: gyrocal applies calibrations in deg/s")
        c_in, c_out = IMUCAL_ACC_UNITS[units["input"]], IMUCAL_ACC_UNITS[units["output"]]
        try:
            K = np.linalg.inv(_matrix(d["R_g"], "R_g")) @ np.linalg.inv(_matrix(d["K_g"], "K_g"))
            b = -K @ _vector(d["b_g"], "b_g")
            G = _matrix(d["K_ga"], "K_ga") * c_out
            A = np.linalg.inv(_matrix(d["R_a"], "R_a")) @ np.linalg.inv(_matrix(d["K_a"], "K_a")) * (c_in / c_out)
            o = _vector(d["b_a"], "b_a") / c_in
        except KeyError as exc:
            raise CorrectionFileError(f"the imucal file has no {exc.args[0]}") from None
        except np.linalg.LinAlgError:
            raise CorrectionFileError("the imucal file's scale or rotation matrix cannot be inverted") from None
        identity = np.allclose(A, np.eye(3)) and not np.any(o)
        return cls(K=K, b=b, G=None if not np.any(G) else G, A=None if identity else A, o=None if identity else o, source="imucal")

    def apply(self, gyro: np.ndarray, accel: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """Calibrated rates (deg/s) and, when the accelerometer is calibrated and given, specific force (g)."""
        a_cal = None
        if accel is not None:
            r = np.asarray(accel, float)
            a_cal = r if self.A is None or self.o is None else (r - self.o) @ self.A.T
        m = np.asarray(gyro, float)
        if self.G is not None and a_cal is not None:
            m = m - a_cal @ self.G.T
        return m @ self.K.T + self.b, (a_cal if self.A is not None else None)

    def to_json(self) -> dict[str, Any]:
        """gyrocal's calibration JSON: k, b, K, G and the accelerometer's model (or null)."""
        return {
            "model": "g = K (m - G a) + b",
            "k": [float(v) for v in np.diag(self.K)],
            "b": [float(v) for v in self.b],
            "K": self.K.tolist(),
            "G": None if self.G is None else self.G.tolist(),
            "accelerometer": None if self.A is None or self.o is None else {"model": "a = A (r - o)", "matrix": self.A.tolist(),
                                                                            "offset": [float(v) for v in self.o]},
            "identity": None if self.identity is None else self.identity.to_json(),
        }

    def to_imucal(self, comment: str = "") -> dict[str, Any]:
        """An imucal Ferraris calibration file's JSON (``imucal.management.load_calibration_info`` loads it)."""
        Kinv = np.linalg.inv(self.K)
        # R_a = I and K_a = A^-1: imucal applies R_a^-1 K_a^-1 = A
        K_a, b_a = (np.eye(3), np.zeros(3)) if self.A is None or self.o is None else (np.linalg.inv(self.A), self.o)
        R_a = np.eye(3)
        return {
            "cal_type": "Ferraris", "_format_version": IMUCAL_FORMAT,
            "acc_unit": "g", "gyr_unit": "deg/s", "from_acc_unit": "g", "from_gyr_unit": "deg/s", "comment": comment,
            "K_a": K_a.tolist(), "R_a": R_a.tolist(), "b_a": [float(v) for v in b_a],
            "K_g": Kinv.tolist(), "R_g": np.eye(3).tolist(), "K_ga": (np.zeros((3, 3)) if self.G is None else self.G).tolist(),
            "b_g": [float(v) for v in -Kinv @ self.b],
        }


def read_correction(path: str | os.PathLike[str]) -> Correction:
    """A calibration file on disk (gyrocal's JSON or imucal's); CorrectionFileError saying what is wrong and what to give."""
    p = Path(path)
    try:
        return Correction.from_json(json.loads(p.read_text(encoding="utf-8")))
    except FileNotFoundError:
        raise CorrectionFileError(f"{p} does not exist; give the path of a calibration JSON file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CorrectionFileError(f"{p} cannot be read ({exc}); give gyrocal's or imucal's calibration JSON") from None
    except json.JSONDecodeError as exc:
        raise CorrectionFileError(f"{p} is not JSON ({exc.msg} at line {exc.lineno}); give gyrocal's or imucal's calibration "
                                  "file") from None
    except CorrectionFileError as exc:
        raise CorrectionFileError(f"{p}: {exc}") from None


def _vector(v: Any, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise CorrectionFileError(f"\"{name}\" must be three finite numbers, got {v!r}")
    return a


def _matrix(v: Any, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.shape != (3, 3) or not np.all(np.isfinite(a)):
        raise CorrectionFileError(f"\"{name}\" must be a 3x3 matrix of finite numbers")
    return a


def _accel(acc: Any) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The accelerometer's A and o from a calibration's ``accelerometer`` entry: gyrocal's fitted model (scale, bias,
    misalignment) or a written one (matrix, offset); (None, None) when it has none."""
    if not isinstance(acc, dict):
        return None, None
    if "matrix" in acc:
        return _matrix(acc["matrix"], "accelerometer.matrix"), _vector(acc["offset"], "accelerometer.offset")
    fitted = AccelCalibration.from_dict(acc)
    return fitted.matrix, fitted.offset


def corrected(rec: Recording, correction: Correction) -> Recording:
    """The recording with its gyroscope (and, when the correction calibrates it, accelerometer) corrected; times,
    counters, temperatures and the rest unchanged."""
    gyro, accel = correction.apply(rec.gyro, rec.accel)
    return replace(rec, gyro=gyro, accel=rec.accel if accel is None else accel)
