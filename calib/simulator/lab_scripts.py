"""Scripts of the other calibration protocols, for comparing methods on the same simulated sensor.

- ``multi_position_script``: imu_tk's protocol (a long rest, then hand re-orientations between rests);
- ``inclined_script``: the accelerometer-aided method as the paper ran it: the device on a plane inclined
  0, 30 and 45 deg, turned in 90 deg steps about the plane's normal between rests, then tipped over;
- ``ferraris_script``: Ferraris' six static poses (each axis up, then down), then a full turn about each axis;
- ``rate_table_script``: a turntable or servomotor turning the device about each axis at given rates,
  both ways, a rest between runs.

``with_accelerometer_error`` gives a simulated recording's accelerometer a random 9-parameter error, for
the methods that take gravity as their reference.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from calib.recording import Recording
from calib.simulator.protocol import Motion, ProtocolScript, Segment, Still, Turn
from calib.simulator.ranges import STILL_S
from calib.units import FULL_TURN_DEG

LINEAR = (0.25, 0.5, 0.75)  # evenly spread speed-profile controls: a steady run between a smooth start and stop


def multi_position_script(rng: np.random.Generator, n: int = 36, first_rest_s: float = 50.0, rest_s: float = 5.0,
                          vertical_only: bool = False) -> ProtocolScript:
    """A ``first_rest_s`` rest, then ``n`` re-orientations of 90-180 deg about random axes (1.5-3 s) between rests."""
    segs: list[Segment] = [Still(first_rest_s)]
    for _ in range(n):
        axis = np.array([0.0, 0.0, 1.0]) if vertical_only else rng.standard_normal(3)
        angle = rng.uniform(90.0, 180.0)
        segs += [Motion(tuple(angle * axis / np.linalg.norm(axis)), duration_s=float(rng.uniform(1.5, 3.0))), Still(rest_s)]
    return ProtocolScript(tuple(segs))


def inclined_script(rng: np.random.Generator, inclinations_deg: Sequence[float] = (0.0, 30.0, 45.0),
                    rest_s: float = 10.0, first_rest_s: float = 50.0) -> ProtocolScript:
    """For each inclination and each body axis: tilt the device so that axis is the plane's normal, then four
    90 deg turns about it between rests. The plane's tilt is what lets the accelerometer see the turns."""
    segs: list[Segment] = [Still(first_rest_s)]
    for incl in inclinations_deg:
        for axis in range(3):
            other = np.zeros(3)
            other[(axis + 1) % 3] = incl + rng.uniform(-2.0, 2.0)
            segs += [Motion(tuple(other), duration_s=1.5), Still(rest_s)]
            for _ in range(4):
                turn = np.zeros(3)
                turn[axis] = 90.0
                segs += [Motion(tuple(turn), duration_s=float(rng.uniform(1.5, 2.5))), Still(rest_s)]
            segs += [Motion(tuple(-other), duration_s=1.5), Still(rest_s)]
    return ProtocolScript(tuple(segs))


# (rotation vector in deg, body axes) of each re-orientation between Ferraris' poses, starting z up:
# z up -> z down -> y up -> y down -> x up -> x down (the tilts are checked in tests by gravity).
_FERRARIS_MOVES = ((180.0, 0.0, 0.0), (90.0, 0.0, 0.0), (180.0, 0.0, 0.0), (0.0, 0.0, 90.0), (0.0, 180.0, 0.0))


def ferraris_script(rng: np.random.Generator, rest_s: float = 5.0) -> ProtocolScript:
    """Ferraris' protocol: the six static poses (rests of ``rest_s``), then a full hand turn about x, y and z."""
    segs: list[Segment] = [Still(rest_s)]
    for move in _FERRARIS_MOVES:
        segs += [Motion(move, duration_s=float(rng.uniform(1.5, 2.5))), Still(rest_s)]
    for axis in ("x", "y", "z"):
        segs += [Turn(axis, FULL_TURN_DEG, duration_s=float(rng.uniform(2.5, 5.0)), tilt=rng.uniform(-0.1, 0.1, 2)),
                 Still(STILL_S)]
    return ProtocolScript(tuple(segs))


def rate_table_script(rates_dps: Sequence[float], run_s: float, rest_s: float = 2.0,
                      tilt: np.ndarray | None = None) -> ProtocolScript:
    """Runs about x, y, z at each rate both ways, ``run_s`` each (angle rate * run_s, the simulator's smooth start and
    stop inside), ``rest_s`` between them.

    ``tilt``: (3, 2) off-axis components of each axis' mounting (a servo's fixture); None: exact (a turntable).
    """
    segs: list[Segment] = [Still(rest_s)]
    for i, axis in enumerate(("x", "y", "z")):
        for rate in rates_dps:
            for sign in (1.0, -1.0):
                segs += [Turn(axis, sign * rate * run_s, duration_s=run_s, wobble_deg=0.0,
                              tilt=0 if tilt is None else tilt[i], profile=LINEAR), Still(rest_s)]
    return ProtocolScript(tuple(segs))


def with_accelerometer_error(rec: Recording, rng: np.random.Generator) -> tuple[Recording, np.ndarray]:
    """``rec`` with its accelerometer read through a random scale (0.97-1.03), offset (+-50 mg) and
    misalignment (+-0.01 rad) in ``calib.estimators.accel``'s model; and the true (scale, offset)."""
    from calib.estimators.accel import AccelCalibration

    if rec.accel is None:
        return rec, np.full(6, np.nan)
    scale, offset, mis = rng.uniform(0.97, 1.03, 3), rng.uniform(-0.05, 0.05, 3), rng.uniform(-0.01, 0.01, 3)
    M = AccelCalibration(scale=scale, offset=offset, misalignment=mis).matrix
    raw = np.linalg.solve(M, rec.accel.T).T + offset
    return replace(rec, accel=raw), np.concatenate([scale, offset])
