"""One entry point for every estimator: ``calibrate(recording, method=...)``."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from importlib import import_module

from .errors import GyrocalError
from .recording import Recording
from .result import CalibrationResult
from .stage import Stage

# method name -> (module, function); imported on first use so each estimator stays independent.
_METHODS: dict[str, tuple[str, str]] = {
    "closure": ("calib.closure", "calibrate_closure"),
    "paper": ("calib.paper", "calibrate_paper"),
}
DEFAULT_METHOD = "closure"


def available_methods() -> list[str]:
    """Names accepted by ``calibrate(method=...)``."""
    return list(_METHODS)


def _estimator(method: str) -> Callable[..., CalibrationResult]:
    if method not in _METHODS:
        raise GyrocalError(f"unknown method {method!r}: choose one of {', '.join(_METHODS)}")
    module, name = _METHODS[method]
    return getattr(import_module(module), name)


def calibrate(rec: Recording, method: str = DEFAULT_METHOD, stages: list[Stage] | None = None) -> CalibrationResult:
    """Calibrate one recording of the protocol (still, then full turns about x, y, z).

    Stages are detected from the data when not given. Raises RecordingError for bad input and
    ProtocolError when a stage of the protocol is missing.
    """
    result = _estimator(method)(rec, stages=stages)
    return replace(result, sample_rate_hz=rec.fs, n_samples=len(rec))
