"""Where the hand put the device back after each turn, as the accelerometer measures it (calib.stages.placement):
the tilt of a placement error the simulator puts in is read back within its standard deviation, in its direction; a
device put back exactly reads no tilt; without an accelerometer nothing is claimed."""

from __future__ import annotations

import numpy as np
import pytest

from calib.effects.placement import PlacementError
from calib.estimators.closure.placement import HEADING_PRIOR_DEG
from calib.pipeline import calibrate
from calib.simulator import simulate

ERRORS_DEG = np.array([[0.8, -0.5, 0.6], [-0.4, 0.9, -0.7], [0.3, 0.2, 1.0]])  # per turn: tilt x, tilt y, heading


@pytest.mark.parametrize("seed", range(4))
def test_each_turns_tilt_is_read_back_within_its_standard_deviation(seed: int) -> None:
    rec, _ = simulate(seed, noise=0.05, effects=[PlacementError(errors_deg=ERRORS_DEG)])
    placement = calibrate(rec, method="closure").quality["placement"]
    assert placement["measured_by"] == "accelerometer" and "heading" in placement["note"]
    rows = placement["turns"]
    assert [t["axis"] for t in rows] == ["x", "y", "z"]
    for row, err in zip(rows, ERRORS_DEG, strict=True):
        # the device rests flat between turns, so its axes are the start frame's: the tilt is (tilt x, tilt y, 0)
        got = np.asarray(row["rotation_deg"])
        sd = row["tilt_std_deg"]
        assert 0.003 < sd < 0.03, sd
        assert np.all(np.abs(got[:2] - err[:2]) < 4 * sd + 0.02), (got, err)  # + the small-angle model's 1 % of 1 deg
        assert abs(got[2]) < 0.05  # the heading is not seen
        assert row["tilt_deg"] == pytest.approx(float(np.linalg.norm(got)))


def test_a_device_put_back_exactly_reads_no_tilt_beyond_its_noise() -> None:
    z = []
    for seed in range(6):
        rec, _ = simulate(seed, noise=0.05)
        for row in calibrate(rec, method="closure").quality["placement"]["turns"]:
            z.extend(np.asarray(row["rotation_deg"])[:2] / row["tilt_std_deg"])
    assert 0.6 < np.sqrt(np.mean(np.square(z))) < 1.4, z  # about 1 when the standard deviation is honest


def test_without_an_accelerometer_the_placement_is_carried_as_a_prior_and_said() -> None:
    rec, _ = simulate(1, noise=0.05)
    blind = rec.__class__(t=rec.t, gyro=rec.gyro, accel=None, seq=rec.seq, meta=rec.meta)
    result = calibrate(blind, method="closure")
    placement = result.quality["placement"]
    assert placement["measured_by"] is None and placement["turns"] == []
    assert placement["note"].startswith("no accelerometer: the pose the device was put back in is not measured: the "
                                        "calibration carries each turn's placement (tilt and heading) as a prior of 0.1 deg")
    assert placement["heading_prior_deg"] == placement["tilt_prior_deg"] == HEADING_PRIOR_DEG
    # both parts of every turn are a prior: k_x and k_y are as uncertain as k_z, each at least the prior's worth
    seen = calibrate(rec, method="closure")
    assert np.all(result.k_std > 0.5 * np.radians(HEADING_PRIOR_DEG) / (2 * np.pi))
    assert np.all(result.k_std[:2] > 5 * seen.k_std[:2])


def test_a_turn_with_another_motion_between_it_and_a_rest_has_no_placement_claimed() -> None:
    """The rest before a turn must be the pose the turn began from: a motion between them (a re-orientation, a turn
    left out) leaves that turn's placement unmeasured, the others measured."""
    from dataclasses import replace

    from calib.stages.detector import detect_stages
    from calib.stages.placement import measure_placement

    rec, _ = simulate(2, noise=0.05)
    stages = detect_stages(rec)
    stills = [s for s in stages if s.kind == "still"]
    turns = [s for s in stages if s.kind == "turn"]
    first = stills[0]
    cut = first.end - 20  # the rest's last 20 samples become a motion of their own
    shorter = replace(first, end=cut, end_s=float(rec.t[cut]))
    nudge = replace(first, kind="motion", start=cut, start_s=float(rec.t[cut]), axis=None, angle_deg=None, flags=())
    rows = measure_placement(rec, turns, [shorter, *stills[1:]], [shorter, nudge, *stages[1:]])["turns"]
    assert [r["tilt_deg"] is None for r in rows] == [True, False, False], rows
    assert all(r["tilt_std_deg"] is not None for r in rows[1:])
