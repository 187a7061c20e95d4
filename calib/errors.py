"""Errors raised by gyrocal's numerics. Each message says what is wrong and how to fix it."""

from __future__ import annotations


class GyrocalError(Exception):
    """Base class for every error a user may see; the message is meant for people."""


class RecordingError(GyrocalError):
    """The recording cannot be read or fails validation (bad file, bad values, bad layout)."""


# Every reason a read recording can be refused, in a word: the ``code`` of a Refusal, the CLI's ``{"error": {"code"}}``.
REFUSAL_CODES = {
    "turn_missing": "a full turn about an axis was not found",
    "still_missing": "no rest long enough before the first turn",
    "no_rest": "no rest anywhere (the device was held in the hand)",
    "sample_rate_suspect": "the recording holds the protocol at another sample rate",
    "sections_incomplete": "the labelled sections do not hold every motion between two rests",
    "protocol_not_found": "the protocol asked for is not in the recording",
    "not_determined": "the motions do not determine every parameter",
    "not_closed": "a turn does not end where it began",
    "reorientations_disagree": "no calibration makes the re-orientations agree with the accelerometer",
    "accelerometer_not_determined": "the rests cannot calibrate the accelerometer",
    "not_one_motion": "a kit's recordings are not of one motion of one tray (a wearable did not turn with the others)",
    "not_calibrated": "any other reason the estimator gave",
    "not_a_rest": "a noise analysis was asked of a recording that moves",
    "rest_too_short": "the rest is too short for an Allan analysis",
}


class Refusal(GyrocalError):
    """The recording was read, and cannot be calibrated as asked: ``code`` says why in a word, ``stages`` are the
    stages that were found, so a caller can show them. The command line exits 3 on every refusal."""

    default_code = "not_calibrated"

    def __init__(self, message: str, *, code: str | None = None, stages: list | None = None) -> None:
        super().__init__(message)
        self.code = code or self.default_code
        self.stages = list(stages or [])


class ProtocolError(Refusal):
    """The recording is valid but does not contain the calibration protocol (a stage is missing).

    ``code``: turn_missing, still_missing, no_rest, sample_rate_suspect, sections_incomplete, protocol_not_found.
    """

    default_code = "protocol_not_found"


class KitRefusal(Refusal):
    """A kit's recordings cannot be calibrated together: ``wearable`` (its name) does not follow the motion of
    ``reference``, the wearable it was compared with (code not_one_motion), or the kit's motion holds no protocol
    (turn_missing)."""

    default_code = "not_one_motion"

    def __init__(self, message: str, *, code: str | None = None, wearable: str | None = None,
                 reference: str | None = None) -> None:
        super().__init__(message, code=code)
        self.wearable, self.reference = wearable, reference


def error_code(exc: GyrocalError) -> str:
    """The one word every door gives for a recording it could not read or calibrate: ``bad_sections`` or
    ``bad_recording`` for one that cannot be read, a Refusal's ``code``, else ``not_calibrated``."""
    if isinstance(exc, SectionsError):
        return "bad_sections"
    if isinstance(exc, RecordingError):
        return "bad_recording"
    if isinstance(exc, Refusal):
        return exc.code
    return "not_calibrated"


class OutputError(GyrocalError):
    """A result cannot be written where asked (a missing folder, no permission)."""


class CalibrationError(Refusal):
    """The estimator could not produce a trustworthy result from this recording.

    ``code``: not_determined (the motions do not determine the parameters), not_closed (a turn does not end where it
    began), reorientations_disagree, accelerometer_not_determined, not_calibrated (any other reason).
    """

    default_code = "not_determined"


class RecordingTooLong(RecordingError):
    """The work a recording asks for (its samples, once lost ones are put back) is beyond the limit set."""


class SectionsError(RecordingError):
    """The labelled sections given with a recording cannot be read or do not fit it."""


class SampleRateUnknownError(RecordingError):
    """The file has no time column and no sample rate was given."""
