"""gyrocal's numerics: recordings, stage detection, estimators, the protocol simulator, diagnosis, noise.

The Python API (docs/python.md) is ``calib.read``, ``calib.calibrate``, ``calib.diagnose``, ``calib.noise_report``,
``calib.correct``, ``calib.load_calibration``, ``calib.fetch_calibration``, ``calib.watch_report``, ``calib.simulate``,
``calib.write_csv`` and the exports ``calib.kalibr_imu_yaml`` and ``calib.openvins_imu_chain`` (calib.api), loaded on
first use so that ``import calib`` stays quick. This package imports nothing else of gyrocal's.
"""

from typing import Any

from calib.errors import CalibrationError, GyrocalError, ProtocolError, RecordingError, Refusal
from calib.recording import Recording, RecordingMeta
from calib.result import CalibrationResult
from calib.stages.stage import Stage

__version__ = "0.1.0"

_API = ("calibrate", "correct", "diagnose", "fetch_calibration", "kalibr_imu_yaml", "load_calibration", "noise_report",
        "openvins_imu_chain", "read", "simulate", "watch_report", "write_csv")


def __getattr__(name: str) -> Any:
    if name in _API:
        from calib import api

        return getattr(api, name)
    raise AttributeError(f"module 'calib' has no attribute {name!r}")


__all__ = [
    "CalibrationError",
    "CalibrationResult",
    "GyrocalError",
    "ProtocolError",
    "Recording",
    "RecordingMeta",
    "RecordingError",
    "Refusal",
    "Stage",
    "__version__",
    *_API,
]
