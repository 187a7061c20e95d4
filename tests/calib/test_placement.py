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


# ---- the heading spread, learned from the turns that show it ----------------------------------------------------------


def _results_at(tilt_deg: float, heading_deg: float, noise: float, seeds: range) -> list[tuple]:
    """(result, truth) of ``seeds`` simulated hands putting the device back tilted and turned by the spreads given."""
    out = []
    for seed in seeds:
        rec, truth = simulate(seed, noise=noise, effects=[PlacementError(tilt_deg, heading_std_deg=heading_deg)])
        out.append((calibrate(rec, method="closure", stages=list(truth.stages)), truth))
    return out


@pytest.fixture(scope="module")
def sloppy_hands() -> list[tuple]:
    # 1 deg of tilt and heading per turn: the turns about x and y show the hand's heading, the turn about z carries it
    return _results_at(1.0, 1.0, 0.05, range(40))


def test_a_sloppy_hands_heading_is_learned_and_k_z_is_as_uncertain_as_it_says(sloppy_hands) -> None:
    z = np.array([(res.k - truth.k) / res.k_std for res, truth in sloppy_hands])
    assert 0.7 < np.std(z[:, 2]) < 1.4, np.std(z, axis=0)  # was 2.9: k_z three times too confident
    assert np.all((0.7 < np.std(z[:, :2], axis=0)) & (np.std(z[:, :2], axis=0) < 1.4))  # were 0.3-0.4: too wide


def test_k_z_interval_holds_the_truth_as_often_as_it_says(sloppy_hands) -> None:
    covered = [res.interval(0.95)[0][2, 0] <= truth.k[2] <= res.interval(0.95)[0][2, 1] for res, truth in sloppy_hands]
    assert np.mean(covered) >= 0.85


def test_a_sloppy_hands_k_z_is_as_good_as_if_its_heading_spread_were_known() -> None:
    # 2 deg of heading: the turns about x and y alone leave a spread under half the true one in a fifth of recordings,
    # and the turn about z, weighed as if the hand were careful, moved k_z (rms 1.29x the told estimator's on these)
    learned, told = [], []
    for seed in range(100):
        rec, truth = simulate(seed, noise=0.03, effects=[PlacementError(1.0, heading_std_deg=2.0)])
        stages = list(truth.stages)
        learned.append(calibrate(rec, method="closure", stages=stages).k[2] - truth.k[2])
        told.append(calibrate(rec, method="closure", stages=stages, heading_prior_deg=2.0).k[2] - truth.k[2])
    ratio = float(np.sqrt(np.mean(np.square(learned)) / np.mean(np.square(told))))
    assert ratio < 1.12, ratio


@pytest.mark.parametrize("seed", [5, 6])
def test_a_careful_hands_turn_about_the_vertical_stopped_short_is_never_passed_as_heading(seed: int) -> None:
    # 6 deg short with a hand that puts the device back within 0.1 deg: whether the turn joins the spread's evidence
    # (the others then say k_z) or not (k_z then leans on it), its calibrated closure stays far beyond the 0.25 deg a
    # full turn comes back within, so the session asks that turn again
    from calib.judge.acceptance import Tolerances, misclosure
    from calib.simulator import ProtocolScript, Still, Turn

    script = ProtocolScript((Still(3.0), Turn("x", 360.0, 3.5), Still(3.0), Turn("y", 360.0, 3.5), Still(3.0),
                             Turn("z", 354.0, 3.5), Still(3.0)))
    rec, truth = simulate(seed, noise=0.03, script=script, effects=[PlacementError(0.1, heading_std_deg=0.1)])
    res = calibrate(rec, method="closure", stages=list(truth.stages))
    miss = {t["axis"]: float(misclosure(t)) for t in res.residuals["turns"]}
    assert miss["z"] > 2 * Tolerances().closure_max_deg > max(miss["x"], miss["y"]), miss
    heading = res.quality["placement"]["heading"]
    if heading["turns"] == 3:  # joined: the spread took the miss, k_z is the other turns' and honest
        assert abs(res.k[2] - truth.k[2]) < 3 * res.k_std[2]


def test_a_careful_hand_is_calibrated_as_if_its_heading_were_known() -> None:
    # no placement error: k_z as good as the estimator told there is none (ten times better than a 0.1 deg prior)
    learned, told, prior = [], [], []
    for seed in range(12):
        rec, truth = simulate(seed, noise=0.03)
        stages = list(truth.stages)
        learned.append(calibrate(rec, method="closure", stages=stages).k[2] - truth.k[2])
        told.append(calibrate(rec, method="closure", stages=stages, heading_prior_deg=0.0).k[2] - truth.k[2])
        prior.append(calibrate(rec, method="closure", stages=stages, heading_prior_deg=HEADING_PRIOR_DEG).k[2] - truth.k[2])
    rms = [float(np.sqrt(np.mean(np.square(e)))) for e in (learned, told, prior)]
    assert rms[0] < 1.5 * rms[1] and rms[0] < 0.5 * rms[2], rms


def test_the_heading_spread_says_where_it_came_from() -> None:
    rec, truth = simulate(3, noise=0.05, effects=[PlacementError(0.5, heading_std_deg=0.5)])
    heading = calibrate(rec, method="closure").quality["placement"]["heading"]
    assert heading["source"] == "estimated" and heading["turns"] == 3 and 0.0 < heading["spread_deg"] < 3.0
    assert heading["spread_sd_deg"] is not None
    assert "learned from the closures of 2 turn(s) about horizontal axes and 1 about the vertical" in heading["note"]
    stated = calibrate(rec, method="closure", heading_prior_deg=0.25).quality["placement"]
    assert stated["heading"]["source"] == "stated" and stated["heading_prior_deg"] == stated["heading"]["spread_deg"] == 0.25
    # no accelerometer: no turn's vertical is known, the default prior is carried and the page says how to state one
    blind = rec.__class__(t=rec.t, gyro=rec.gyro, accel=None, seq=rec.seq, meta=rec.meta)
    default = calibrate(blind, method="closure").quality["placement"]["heading"]
    assert default["source"] == "default" and default["spread_deg"] == HEADING_PRIOR_DEG
    assert "--heading-prior-deg" in default["note"]


def test_turns_about_the_vertical_alone_show_no_heading() -> None:
    # every turn about the vertical (as on a turntable, Ferraris' way): heading and scale factor cannot be told apart
    from calib.estimators.closure.heading import heading_evidence
    from calib.stages.placement import measure_tilts

    rec, truth = simulate(4, noise=0.05)
    turns = [s for s in truth.stages if s.kind == "turn"]
    stills = [s for s in truth.stages if s.kind == "still"]
    tilts = measure_tilts(rec, turns, stills, list(truth.stages))
    swept = np.array([[0.0, 0.0, 360.0]] * len(turns))  # as if each had been about the device's z, the vertical here
    assert heading_evidence(tilts, swept).turns == 0
    about_axes = np.array([[360.0 if a == s.axis else 0.0 for a in "xyz"] for s in turns])
    assert heading_evidence(tilts, about_axes).shows.tolist() == [s.axis != "z" for s in turns]
