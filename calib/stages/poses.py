"""Ferraris' six static poses among a recording's rests (told apart by gravity), and its full turns by axis."""

from __future__ import annotations

import numpy as np

from calib.recording import Recording
from calib.stages.stage import AXES, POSES, Stage

MIN_POSE_COS = np.cos(np.radians(30.0))  # a still counts as a pose when gravity is within 30 deg of that axis


def find_poses(rec: Recording, stills: list[Stage]) -> dict[str, Stage]:
    """Ferraris' six poses among the stills, from the accelerometer: for each of +x, -x, +y, ... up, the
    longest still whose gravity lies within 30 deg of that axis. Poses not found are left out."""
    if rec.accel is None:
        return {}
    found: dict[str, Stage] = {}
    for s in stills:
        a = rec.accel[s.start:s.end].mean(axis=0)
        norm = float(np.linalg.norm(a))
        if not np.isfinite(norm) or norm == 0:
            continue
        u = a / norm
        i = int(np.argmax(np.abs(u)))
        if abs(u[i]) < MIN_POSE_COS:
            continue
        pose = f"{AXES[i]}_{'p' if u[i] > 0 else 'a'}"
        if pose not in found or s.n > found[pose].n:
            found[pose] = s
    return {p: found[p] for p in POSES if p in found}


def ferraris_turns(stages: list[Stage]) -> dict[str, Stage]:
    """The longest full turn about each axis."""
    turns: dict[str, Stage] = {}
    for s in stages:
        if s.kind == "turn" and s.axis is not None and (s.axis not in turns or s.n > turns[s.axis].n):
            turns[s.axis] = s
    return turns
