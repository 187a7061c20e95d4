"""Protocol recognition: which calibration protocol a recording holds, from its stages.

- ``ferraris``: six static poses (each axis up, then down, told apart by gravity) and a full turn about
  each axis (Ferraris et al. 1995; imucal);
- ``paper``: rests and a full turn about each axis (the in-field protocol gyrocal was built for);
- ``multi-position``: no full turn about every axis, but at least ``MIN_MOTIONS`` re-orientations between
  rests with the accelerometer recorded (imu_tk's protocol);
- ``mixed``: some full turns and enough re-orientations, used together by the multi-position estimator;
- ``hand-held``: no rest anywhere, even the quietest second varies more than a gyroscope on a table: the
  device was held in the hand throughout;
- ``unrecognised``: none of these.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.numerics.windows import span_means
from calib.quality import Recognition as RecognitionJson
from calib.recording import Recording
from calib.stages.hints import never_at_rest
from calib.stages.poses import ferraris_turns, find_poses
from calib.stages.stage import AXES, Stage

MIN_MOTIONS = 6  # re-orientations needed before the three scale factors can be separated
MIN_TILT_DEG = 10.0  # a motion between rests counts as a re-orientation when gravity moves this much in the body


@dataclass(frozen=True)
class Recognition:
    """What protocol a recording holds, and the counts that say so."""

    name: str
    rests: int
    full_turns: tuple[str, ...]  # axes of the full turns, in recording order
    poses: tuple[str, ...]  # Ferraris poses found (x_p, x_a, ...)
    reorientations: int  # motions between rests that tilt the device
    quietest_second: tuple[float, float] | None = None  # hand-held: (start s, std deg/s) of its quietest second

    @property
    def summary(self) -> str:
        """One sentence for people."""
        turns = f"{len(self.full_turns)} full turn(s)" + (f" (about {', '.join(self.full_turns)})" if self.full_turns else "")
        parts = {
            "ferraris": f"Ferraris' protocol: the six static poses and {turns}",
            "paper": f"rests and {turns}",
            "multi-position": f"{self.reorientations} re-orientations between {self.rests} rests, no full turn about every axis",
            "mixed": f"{turns} and {self.reorientations} re-orientations between {self.rests} rests",
            "hand-held": "no rest anywhere: the device was held in the hand throughout",
            "unrecognised": f"{self.rests} rest(s), {turns}, {self.reorientations} re-orientation(s)",
        }
        return parts[self.name]

    def to_dict(self) -> RecognitionJson:
        """JSON-ready form."""
        return {"name": self.name, "summary": self.summary, "rests": self.rests, "full_turns": list(self.full_turns),
                "poses": list(self.poses), "reorientations": self.reorientations}


def count_reorientations(rec: Recording, stages: list[Stage]) -> int:
    """Motions between consecutive rests after which gravity points elsewhere in the body (needs the accelerometer)."""
    if rec.accel is None:
        return 0
    stills = [s for s in stages if s.kind == "still"]
    if len(stills) < 2:
        return 0
    g = span_means(rec.accel, [(s.start, s.end) for s in stills])
    u = g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
    cos = np.clip(np.sum(u[1:] * u[:-1], axis=1), -1.0, 1.0)
    return int(np.sum(np.degrees(np.arccos(cos)) >= MIN_TILT_DEG))


def recognise(rec: Recording, stages: list[Stage]) -> Recognition:
    """Name the protocol the stages of ``rec`` hold."""
    stills = [s for s in stages if s.kind == "still"]
    turns = [s for s in stages if s.kind == "turn" and s.axis is not None]
    axes = tuple(str(s.axis) for s in turns)
    poses = tuple(find_poses(rec, stills))
    reorient = count_reorientations(rec, stages)
    every_axis = set(AXES) <= set(ferraris_turns(turns))
    held = never_at_rest(rec) if not stills else None
    if held is not None:
        name = "hand-held"
    elif every_axis and len(poses) == 6:
        name = "ferraris"
    elif every_axis:
        name = "paper"
    elif reorient >= MIN_MOTIONS:
        name = "mixed" if turns else "multi-position"
    else:
        name = "unrecognised"
    return Recognition(name, len(stills), axes, poses, reorient, held)
