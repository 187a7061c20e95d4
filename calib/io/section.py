"""The Section type: one run of samples the user labelled (a rest, a Ferraris pose, a full turn)."""

from __future__ import annotations

import re
from dataclasses import dataclass

from calib.errors import RecordingError
from calib.stages.stage import POSES, Axis, StageKind

_STILL = re.compile(r"^(?:still|rest|static)(?:[_-].*)?$")
_TURN = re.compile(r"^([xyz])_rot(?:[_-].*)?$")
_MOTION = re.compile(r"^motion(?:[_-].*)?$")
LABELS_HELP = "x_p, x_a, y_p, y_a, z_p, z_a, still, x_rot, y_rot, z_rot or motion (a suffix such as still_2 is allowed)"


@dataclass(frozen=True)
class Section:
    """One labelled run of samples, positions [start, end) in the recording."""

    label: str
    start: int
    end: int

    @property
    def kind(self) -> StageKind:
        """still, turn or motion, from the label."""
        return label_kind(self.label)

    @property
    def axis(self) -> Axis | None:
        """The turn's axis (x_rot -> x), None for other sections."""
        m = _TURN.match(self.label)
        return m.group(1) if m else None  # type: ignore[return-value]


def label_kind(label: str) -> StageKind:
    """The stage kind a section label stands for; RecordingError for a label gyrocal does not know."""
    if label in POSES or _STILL.match(label):
        return "still"
    if _TURN.match(label):
        return "turn"
    if _MOTION.match(label):
        return "motion"
    raise RecordingError(f"unknown section label {label!r}: label each section {LABELS_HELP}")
