"""Errors raised by gyrocal's numerics. Each message says what is wrong and how to fix it."""

from __future__ import annotations


class GyrocalError(Exception):
    """Base class for every error a user may see; the message is meant for people."""


class RecordingError(GyrocalError):
    """The recording cannot be read or fails validation (bad file, bad values, bad layout)."""


class ProtocolError(GyrocalError):
    """The recording is valid but does not contain the calibration protocol (a stage is missing).

    ``code`` says why in a word (turn_missing, still_missing, no_rest, sample_rate_suspect, protocol_not_found);
    ``stages`` are the stages that were found, so a caller can show them.
    """

    def __init__(self, message: str, *, code: str = "protocol_not_found", stages: list | None = None) -> None:
        super().__init__(message)
        self.code = code
        self.stages = list(stages or [])


class OutputError(GyrocalError):
    """A result cannot be written where asked (a missing folder, no permission)."""


class CalibrationError(GyrocalError):
    """The estimator could not produce a trustworthy result from this recording."""


class RecordingTooLong(RecordingError):
    """The work a recording asks for (its samples, once lost ones are put back) is beyond the limit set."""


class SampleRateUnknownError(RecordingError):
    """The file has no time column and no sample rate was given."""
