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


PROTOCOLS = ("auto", "paper", "multi-position")


def calibrate_protocol(rec: Recording, protocol: str = "auto", method: str = DEFAULT_METHOD) -> tuple[CalibrationResult, str]:
    """Calibrate a recording of ``protocol`` and say which protocol was used.

    "paper": rest, then full turns about x, y, z (``calibrate`` with ``method``). "multi-position": rests
    in many orientations with re-orientations between them, the accelerometer as reference
    (``calib.multi_position``). "auto": the paper protocol when the recording holds it, else
    multi-position when it has an accelerometer; when neither fits, the paper protocol's refusal.
    """
    from .errors import ProtocolError

    if protocol not in PROTOCOLS:
        raise GyrocalError(f"unknown protocol {protocol!r}: choose one of {', '.join(PROTOCOLS)}")
    if protocol == "multi-position":
        from .multi_position import calibrate_multi_position

        return calibrate_multi_position(rec), "multi-position"
    try:
        return calibrate(rec, method=method), "paper"
    except ProtocolError as refusal:
        if protocol == "paper" or rec.accel is None:
            raise
        from .multi_position import calibrate_multi_position

        try:
            return calibrate_multi_position(rec), "multi-position"
        except GyrocalError:
            raise refusal from None  # neither protocol fits: the paper protocol's reason is the one to act on
