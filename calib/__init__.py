"""gyrocal's numerics: recordings, stage detection, estimators, the protocol simulator, diagnosis.

This package imports nothing else of gyrocal's.
"""

from calib.errors import CalibrationError, GyrocalError, ProtocolError, RecordingError
from calib.recording import Recording, RecordingMeta
from calib.result import CalibrationResult
from calib.stages.stage import Stage

__version__ = "0.1.0"

__all__ = [
    "CalibrationError",
    "CalibrationResult",
    "GyrocalError",
    "ProtocolError",
    "Recording",
    "RecordingMeta",
    "RecordingError",
    "Stage",
    "__version__",
]
