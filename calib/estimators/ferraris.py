"""Ferraris' method (method "ferraris"): six static poses and three full turns, solved in closed form.

Ferraris, Grimaldi and Parvis (1995), "Procedure for effortless in-field calibration of three-axis rate
gyros and accelerometers", as imucal implements it (github.com/mad-lab-fau/imucal,
``FerrarisCalibration.compute``), equation by equation:

- accelerometer: from the means of the six poses (each axis up, then down; U_p and U_n, one column per
  axis) the bias b_a = diag(U_p + U_n)/2, the scale K_a = row norms of (U_p - U_n)/2 and the
  misalignment R_a = K_a^-1 (U_p - U_n)/2 (gravity = 1 g here, imucal's 9.81 m/s^2 there);
- gyroscope: the zero-rate offset b_g = the mean reading over all six poses; its sensitivity to
  acceleration K_ga = (gyro mean in the up poses - in the down poses)/2; each turn's readings, less
  b_g + K_ga a (a the calibrated accelerometer), integrated to W (one column per turn); then
  M = W / (n 360 deg), K_g = row norms of M and R_g = K_g^-1 M.

Ferraris' model reads raw = K_g R_g w + K_ga a + b_g. Reported in gyrocal's diagonal g = k m + b as imucal's
users translate it (misalignment and K_ga left out): k = 1/K_g, b = -k b_g; the full K = M^-1, R_g and K_ga
are in ``quality["ferraris"]``. A hand turn's tilted axis reads as misalignment in R_g, which is why the
diagonal is the one applied. The method gives no uncertainty: it is a reference to compare with, not
gyrocal's estimator.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from calib.errors import ProtocolError
from calib.io.validation import check_calibration_input
from calib.quality import Quality
from calib.recording import Recording
from calib.result import CalibrationResult
from calib.stages.poses import ferraris_turns, find_poses
from calib.stages.resolve import resolve_stages
from calib.stages.stage import AXES, POSES, Stage
from calib.units import FULL_TURN_DEG

METHOD = "ferraris"


def ferraris_stages(rec: Recording, stages: list[Stage]) -> tuple[dict[str, Stage], dict[str, Stage]]:
    """Ferraris' six poses and three turns among ``stages``; ProtocolError naming those that are missing."""
    poses = find_poses(rec, [s for s in stages if s.kind == "still"])
    turns = ferraris_turns(stages)
    missing = [p for p in POSES if p not in poses] + [f"{a}_rot" for a in AXES if a not in turns]
    if missing:
        raise ProtocolError(
            f"Ferraris' protocol needs six static poses (each axis pointing up, then down) and one full turn about "
            f"each axis; missing: {', '.join(missing)}. Rest the device on each of its six faces, then turn it "
            "360 degrees about x, y and z")
    return poses, turns


def calibrate_ferraris(rec: Recording, stages: Any = None) -> CalibrationResult:
    """Calibrate one recording of Ferraris' protocol with Ferraris' closed-form equations.

    stages: a list of Stage (e.g. from labelled sections) or None to detect them. Needs the accelerometer
    (it tells the six poses apart) and one full turn about each axis; raises ProtocolError naming what is
    missing.
    """
    check_calibration_input(rec)
    if rec.accel is None:
        raise ProtocolError("Ferraris' method needs the accelerometer: it finds the six static poses by gravity")
    stage_list = resolve_stages(rec, stages).stages if stages is None else sorted(stages, key=lambda s: s.start)
    poses, turns = ferraris_stages(rec, stage_list)

    def mean(channel: np.ndarray, names: tuple[str, ...]) -> np.ndarray:
        return np.stack([channel[poses[p].start:poses[p].end].mean(axis=0) for p in names], axis=1)

    up, down = ("x_p", "y_p", "z_p"), ("x_a", "y_a", "z_a")
    ua_p, ua_n = mean(rec.accel, up), mean(rec.accel, down)
    b_a = np.diag(ua_p + ua_n) / 2
    half = (ua_p - ua_n) / 2
    k_a = np.sqrt(np.diag(half @ half.T))
    r_a = half / k_a[:, None]
    to_g = np.linalg.inv(np.diag(k_a) @ r_a)

    static = np.concatenate([rec.gyro[poses[p].start:poses[p].end] for p in POSES])
    b_g = static.mean(axis=0)
    k_ga = (mean(rec.gyro, up) - mean(rec.gyro, down)) / 2

    dt = rec.intervals_s
    w = np.empty((3, 3))
    expected = np.empty(3)
    for j, axis in enumerate(AXES):
        s = turns[axis]
        acc = (rec.accel[s.start:s.end] - b_a) @ to_g.T
        rate = rec.gyro[s.start:s.end] - b_g - acc @ k_ga.T
        w[:, j] = (rate * dt[s.start:s.end, None]).sum(axis=0)
        expected[j] = FULL_TURN_DEG * max(1, round(abs(w[j, j]) / FULL_TURN_DEG)) * np.sign(w[j, j])
    m = w / expected[None, :]
    k_g = np.sqrt(np.diag(m @ m.T))
    r_g = m / k_g[:, None]
    k = 1.0 / k_g
    b = -k * b_g
    used = [turns[a] for a in AXES] + [poses[p] for p in POSES]
    index = {id(s): i for i, s in enumerate(stage_list)}
    quality: Quality = {
        "model": "diagonal",
        "turns": 3,
        "stills": 6,
        "stages_used": sorted(i for i in (index.get(id(s)) for s in used) if i is not None),
        "ferraris": {
            "K_g": k_g.tolist(),
            "K_full": np.linalg.inv(m).tolist(),  # g = K m + b with R_g's misalignment kept
            "R_g": r_g.tolist(),
            "b_g": b_g.tolist(),
            "K_ga": k_ga.tolist(),  # (deg/s)/g, not part of g = K m + b
            "accelerometer": {"b_a": b_a.tolist(), "K_a": k_a.tolist(), "R_a": r_a.tolist()},
            "turn_angle_deg": expected.tolist(),
        },
    }
    warnings = []
    if float(np.abs(k_ga).max()) > 0.05:
        warnings.append(
            f"the gyro reads up to {np.abs(k_ga).max():.3f} deg/s per g of acceleration (Ferraris' K_ga); g = K m + b "
            "leaves it out")
    return CalibrationResult(k=k, b=b, method=METHOD, stages=stage_list, quality=quality, warnings=warnings)
