"""Ferraris' six static poses among a recording's rests (told apart by gravity), and its full turns by axis."""

from __future__ import annotations

import numpy as np

from calib.numerics.windows import span_means
from calib.recording import Recording
from calib.stages.stage import AXES, POSES, Stage

MIN_POSE_COS = np.cos(np.radians(30.0))  # a still counts as a pose when gravity is within 30 deg of that axis


def find_poses(rec: Recording, stills: list[Stage]) -> dict[str, Stage]:
    """Ferraris' six poses among the stills, from the accelerometer: for each of +x, -x, +y, ... up, the
    longest still whose gravity lies within 30 deg of that axis. Poses not found are left out."""
    if rec.accel is None:
        return {}
    found: dict[str, Stage] = {}
    g = span_means(rec.accel, [(s.start, s.end) for s in stills])
    with np.errstate(invalid="ignore", divide="ignore"):
        u = g / np.linalg.norm(g, axis=1, keepdims=True)
    axis = np.argmax(np.abs(np.nan_to_num(u)), axis=1)
    for s, row, i in zip(stills, u.tolist(), axis.tolist(), strict=True):
        if not np.isfinite(row[i]) or abs(row[i]) < MIN_POSE_COS:
            continue
        pose = f"{AXES[i]}_{'p' if row[i] > 0 else 'a'}"
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
