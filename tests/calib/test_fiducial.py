"""k's and b's intervals where the heading spread is learned from few turns (calib.estimators.closure.fiducial), on
the smallest fit that shows what they do: two turns about horizontal axes show their headings h_0, h_1 (vertical
misclosures), one about the vertical moves k_z, which takes that turn's heading h_2 plus its noise as its error."""

from __future__ import annotations

import numpy as np
import pytest

from calib.distributions import t_isf
from calib.effects.placement import PlacementError
from calib.estimators.closure.estimator import calibrate_closure
from calib.estimators.closure.fiducial import fiducial_halfwidths
from calib.result import CalibrationResult
from calib.simulator import simulate
from calib.units import DEG

J = 3
UP = np.tile([0.0, 0.0, 1.0], (J, 1))
A = np.zeros((J, 3, 1))
A[2, 2, 0] = 1.0  # k_z moves the vertical turn's vertical closure
SHOWS = np.array([True, True, False])


def _halfwidth(h: tuple[float, float], noise: float, weights_spread: float) -> float:
    """k_z's 95 % half-width (rad) from the horizontal turns' vertical closures ``h`` (rad), each turn's reading noise
    ``noise`` (rad, 1 sigma per component), weighed by the fit as if the spread were ``weights_spread`` (rad)."""
    B = np.repeat(np.eye(3)[None] * noise**2, J, axis=0)
    C = B.copy()
    C[:, 2, 2] += weights_spread**2
    r = np.zeros((J, 3))
    r[0, 2], r[1, 2] = h
    return float(fiducial_halfwidths(r, A, C, B, UP, np.ones(J, dtype=bool), SHOWS, np.zeros(0), np.zeros((0, 1)))[0])


@pytest.mark.parametrize(("h_deg", "noise_deg"), [
    ((0.5, -0.3), 1e-6), ((0.2, 0.1), 1e-6), ((2.0, 1.5), 1e-6),
    ((0.1, -0.2), 0.05), ((0.05, 0.04), 0.05), ((0.02, -0.01), 0.05), ((0.002, 0.001), 0.05)])
def test_with_every_turns_noise_alike_it_is_students_prediction_interval_from_the_two_seen(h_deg, noise_deg) -> None:
    # the third closure against two seen, all N(0, noise^2 + tau^2): h_2 / sqrt((h_0^2 + h_1^2) / 2) is Student's t
    # with 2 degrees of freedom, whatever tau and the noise, down to closures far better than the noise says (the
    # spreads drawn then go below 0, to where the turns' covariance stops being one)
    h = (h_deg[0] * DEG, h_deg[1] * DEG)
    exact = float(t_isf(0.025, 2)) * np.sqrt((h[0] ** 2 + h[1] ** 2) / 2)
    assert _halfwidth(h, noise_deg * DEG, 0.3 * DEG) == pytest.approx(exact, rel=0.01)


@pytest.mark.parametrize("ratio", [0.0, 1.0, 10.0])
def test_it_holds_95_percent_of_the_errors_at_any_heading_against_the_noise(ratio) -> None:
    # the headings and the noise drawn as a hand would make them; the fit weighs the turns by the spread it estimates
    rng = np.random.default_rng(7)
    noise = 0.05 * DEG
    held = []
    for _ in range(600):
        h = rng.normal(0.0, ratio * noise, 3) + rng.normal(0.0, noise, 3)
        spread = np.sqrt(max(np.mean(h[:2] ** 2) - noise**2, 0.0))
        held.append(abs(h[2]) <= _halfwidth((h[0], h[1]), noise, spread))
    assert 0.93 <= np.mean(held) <= 0.975, np.mean(held)


def test_a_learned_spreads_interval_is_carried_by_the_result_and_its_stored_form() -> None:
    rec, truth = simulate(3, noise=0.15, effects=[PlacementError(0.3, heading_std_deg=0.3)])
    learned = calibrate_closure(rec, list(truth.stages))
    assert learned.k_interval_scale is not None and learned.k_dof is not None
    interval = learned.interval(0.95)
    assert interval is not None
    half = np.diff(interval[0], axis=1)[:, 0] / 2
    assert half == pytest.approx(t_isf(0.025, learned.k_dof) * learned.k_interval_scale)
    assert not np.allclose(half, t_isf(0.025, learned.k_dof) * learned.k_std, rtol=0.05)  # not the std's
    back = CalibrationResult.from_dict(learned.to_dict())
    assert back.to_dict() == learned.to_dict()
    assert np.allclose(back.interval(0.95)[0], interval[0], rtol=0, atol=1e-9)
    stated = calibrate_closure(rec, list(truth.stages), heading_prior_deg=0.3)
    assert stated.k_interval_scale is None and "k_interval_scale" not in stated.to_dict()["uncertainty"]
