"""The diagnosis on recordings of re-orientations between rests: the constraints the multi-position calibration uses
(zero rate at rest, the gravity each re-orientation carries), a concealed effect found and a clean recording cleared."""

from __future__ import annotations

import numpy as np
import pytest

from calib.diagnosis import diagnose
from calib.effects.axes import AxisMisalignment
from calib.errors import GyrocalError, ProtocolError
from calib.simulator import simulate
from calib.simulator.lab_scripts import multi_position_script


def _recording(seed: int, effects=()):
    rng = np.random.default_rng(seed)
    script = multi_position_script(rng, n=16, first_rest_s=10.0, rest_s=3.0)
    return simulate(seed, noise=0.05, fs=50.0, script=script, accel_noise_g=0.005, effects=list(effects))


def test_a_clean_multi_position_recording_is_explained_by_the_nominal_model():
    rec, truth = _recording(11)
    d = diagnose(rec, n_boot=60)
    assert d.info["protocol"]["used"] == "multi-position"
    assert d.info["accelerometer"]["identified"]  # the accelerometer is calibrated before gravity is compared
    assert d.effects == [] and d.unexplained == []
    out = d.to_dict()
    assert out["nominal"]["turns"] == 16  # every re-orientation is a constraint
    k = np.array(out["nominal"]["k"])
    assert np.all(np.abs(k - truth.k) < 3e-3)
    gravity = [n for n in d.details["features"].names if n.startswith("gravity_")]
    assert len(gravity) == 16


def test_a_concealed_axis_misalignment_is_found_in_the_gravity_the_re_orientations_carry():
    rec, _ = _recording(12, [AxisMisalignment((0.0, 0.0, 0.03))])
    d = diagnose(rec, n_boot=60)
    names = [e["name"] for e in d.effects]
    assert names[:1] == ["axis_misalignment"], names
    off = d.effects[0]["parameters"]["off_diagonal"]
    assert abs(off[2] - 0.03) < 0.006 and abs(off[0]) < 0.006 and abs(off[1]) < 0.006
    assert d.effects[0]["fit"]["after"] < d.effects[0]["fit"]["before"]


def test_the_protocol_asked_for_is_used_or_refused_with_its_reason():
    rec, _ = _recording(13)
    with pytest.raises(ProtocolError, match="full turn.*diagnose it with --protocol multi-position"):
        diagnose(rec, n_boot=20, protocol="paper")
    with pytest.raises(GyrocalError, match="unknown protocol"):
        diagnose(rec, n_boot=20, protocol="turntable")
