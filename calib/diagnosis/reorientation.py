"""Recordings of re-orientations between rests (imu_tk's multi-position protocol), set up for the diagnosis.

The diagnosis compares such a recording with its simulation on the constraints the multi-position
calibration uses (calib.estimators.multi_position.estimator): zero rate at every rest, and for every motion between two
rests the gravity its calibrated rotation carries from the rest after onto the rest before. So:

- the accelerometer is calibrated first (on the rests, jointly with the gyroscope, as ``gyrocal
  calibrate`` does) and the diagnosis reads gravity from the calibrated specific force;
- each rest keeps the samples its accelerometer mean is taken over (``calib.estimators.accel.rest_spans``) and
  each motion is integrated over everything between two such rests;
- a motion that is a full turn stays a turn (it closes); every other motion is a re-orientation whose
  reference rotation is the motion as that first calibration integrates it, so that the closing
  rotation the diagnosis fits against it stays within a degree or so.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calib.diagnosis.data import REORIENTATION, Layout
from calib.diagnosis.null import window_rotations
from calib.estimators.accel import AccelCalibration, rest_spans
from calib.estimators.multi_position.estimator import calibrate_multi_position, motions_between_rests
from calib.recording import Recording
from calib.stages.stage import Stage


@dataclass(frozen=True)
class Reorientations:
    """A multi-position recording prepared for the diagnosis."""

    rec: Recording  # the recording with its accelerometer calibrated (g)
    stages: list[Stage]  # the rests and the windows between them
    accel: AccelCalibration
    K: np.ndarray  # (3, 3) the first calibration's gyro matrix
    b: np.ndarray  # (3,) deg/s
    G: np.ndarray | None  # (3, 3) its g-sensitivity, (deg/s)/g, when it found one

    @property
    def start(self) -> np.ndarray:
        """Starting values (1, 6) of the nominal fit: the first calibration's scale factors and bias."""
        return np.concatenate([np.diag(self.K), self.b])[None]

    def with_references(self, layout: Layout) -> Layout:
        """``layout`` with each re-orientation's reference rotation: the motion the first calibration integrates."""
        rec = self.rec
        m = rec.gyro
        if self.G is not None and rec.accel is not None:
            m = m - rec.accel @ self.G.T
        rate = m @ self.K.T + self.b
        plain = replace(layout, ref=None)  # every window against the identity: the rotation it makes
        turned = window_rotations(plain, rate).as_quat()
        return replace(layout, ref=np.where(layout.moves[:, None], turned, plain.ref_quats()))


def prepare(rec: Recording, stages: list[Stage]) -> Reorientations:
    """Calibrate accelerometer and gyroscope from the re-orientations (calib.estimators.multi_position.estimator) and lay the recording
    out as rests and the windows between them. Raises the calibration's ProtocolError or CalibrationError."""
    result = calibrate_multi_position(rec, stages)
    acc = AccelCalibration.from_dict(result.quality["accelerometer"] or {})
    assert rec.accel is not None  # calibrate_multi_position refuses a recording without one
    cal = replace(rec, accel=acc.apply(rec.accel))
    stills, motions = motions_between_rests(stages)
    spans = rest_spans(stills, rec.fs)
    t = rec.t
    used = sorted({i for mo in motions for i in (mo.rest_before, mo.rest_after)})
    out = [Stage("still", spans[i][0], spans[i][1], float(t[spans[i][0]]), float(t[spans[i][1] - 1])) for i in used]
    for mo in motions:
        a, b = spans[mo.rest_before][1], spans[mo.rest_after][0]
        if b - a < 2:
            continue
        turn = mo.full_turn
        if turn is not None:
            out.append(Stage("turn", a, b, float(t[a]), float(t[b - 1]), turn.axis, turn.angle_deg, turn.flags))
        else:
            out.append(Stage("motion", a, b, float(t[a]), float(t[b - 1]), flags=(REORIENTATION,)))
    K = np.asarray(result.K if result.K is not None else np.diag(result.k), dtype=float)
    G = None if result.G is None else np.asarray(result.G, dtype=float)
    return Reorientations(cal, sorted(out, key=lambda s: s.start), acc, K, np.asarray(result.b, dtype=float), G)

