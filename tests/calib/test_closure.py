"""The closure estimator (calib.estimators.closure.estimator): model, fit, uncertainty, bound, extended model, real data."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib import CalibrationError, ProtocolError, RecordingError
from calib.apply.correction import Correction
from calib.effects import AxisMisalignment
from calib.estimators.bounds import protocol_bound
from calib.estimators.closure.batch import closure_batch, closure_fit_batch
from calib.estimators.closure.estimator import calibrate_closure
from calib.estimators.closure.fit import KPrior
from calib.io.readers import read_recording
from calib.numerics.rotation import closure_terms, left_jacobian, left_jacobian_inv, prefix_products, total_products
from calib.pipeline import calibrate
from calib.recording import Recording
from calib.simulator import ProtocolScript, SensorParams, Still, Turn, simulate, simulate_batch

FS = 104.0
EXACT = 0.0  # the heading prior of a simulated device, which is put back exactly after each turn
IMUCAL_K = np.array([0.97284, 1.01788, 1.00169])  # imucal's Ferraris result, data README
IMUCAL_B = np.array([0.5834, 0.3765, -0.0589])


def errors(result, truth) -> tuple[np.ndarray, np.ndarray]:
    """(estimate - truth) / reported std, and estimate - truth, for k then b."""
    err = np.concatenate((result.k - truth.k, result.b - truth.b))
    std = np.concatenate((result.k_std, result.b_std))
    return err / std, err


def script(*turns: Turn, still_s: float = 3.0) -> ProtocolScript:
    segs: list = [Still(still_s)]
    for t in turns:
        segs += [t, Still(still_s)]
    return ProtocolScript(tuple(segs))


# ------------------------------------------------------------------------------------------ the model


def test_running_products_match_scipy_composition():
    rng = np.random.default_rng(1)
    for n in (3, 41, 300):  # below and above the blocked scan's threshold, with padding
        rv = rng.normal(0.0, 0.1, (n, 5, 3))
        q = Rotation.from_rotvec(rv.reshape(-1, 3)).as_quat().T.reshape(4, n, 5)
        prefix, total = prefix_products(q), total_products(q)
        for s in range(5):
            expected = Rotation.identity()
            for i in range(n):
                expected = expected * Rotation.from_rotvec(rv[i, s])
                if i in (0, n // 2, n - 1):
                    assert (Rotation.from_quat(prefix[:, i, s]).inv() * expected).magnitude() < 1e-12
            assert (Rotation.from_quat(total[:, s]).inv() * expected).magnitude() < 1e-12


def test_left_jacobian_linearises_the_exponential():
    rng = np.random.default_rng(2)
    for scale in (0.004, 0.8):  # series branch and closed form
        v = rng.normal(0.0, scale, (6, 3))
        dv = rng.normal(0.0, 1e-7, (6, 3))
        moved = Rotation.from_rotvec(np.einsum("bij,bj->bi", left_jacobian(v), dv)) * Rotation.from_rotvec(v)
        assert np.max((Rotation.from_rotvec(v + dv) * moved.inv()).magnitude()) < 1e-12
        assert np.allclose(np.matmul(left_jacobian_inv(v), left_jacobian(v)), np.eye(3), atol=1e-12)


def _turn_like(rng, n=120, B=2, rate=200.0):
    """Readings of B made-up smooth motions (not closing), with the second one shorter (padding)."""
    m = np.cumsum(rng.normal(0.0, 4.0, (n, B, 3)), axis=0) + np.array([rate, 20.0, -30.0])
    dt = np.full((n, B), 1.0 / FS)
    dt[n - 20 :, B - 1] = 0.0 if B > 1 else 1.0 / FS
    K = np.diag([1.02, 0.97, 1.1]) + rng.normal(0.0, 0.01, (B, 3, 3))
    b = rng.normal(0.0, 2.0, (B, 3))
    return m, dt, K, b


@pytest.mark.parametrize("rate", [200.0, 1500.0])  # small increments (series) and large ones (closed form)
def test_closure_jacobian_matches_finite_differences(rate):
    m, dt, K, b = _turn_like(np.random.default_rng(3), rate=rate)
    terms = closure_terms(m, dt, K, b)
    h = 1e-6
    r = lambda K_, b_: closure_terms(m, dt, K_, b_, jacobian=False).r  # noqa: E731
    for i in range(3):
        for j in range(3):
            E = np.zeros((3, 3))
            E[i, j] = h
            fd = (r(K + E, b) - r(K - E, b)) / (2 * h)
            assert np.allclose(terms.dK[:, :, i, j], fd, rtol=1e-6, atol=1e-8)
        e = np.zeros(3)
        e[i] = 1e-4  # deg/s: the b-derivatives are small, so a larger step keeps rounding out
        fd = (r(K, b + e) - r(K, b - e)) / 2e-4
        assert np.allclose(terms.db[:, :, i], fd, rtol=1e-6, atol=1e-10)


def test_closure_noise_covariance_is_the_propagated_reading_noise():
    rng = np.random.default_rng(4)
    m, dt, K, b = _turn_like(rng, n=40, B=1)
    sigma = np.array([[0.05, 0.1, 0.2]])
    terms = closure_terms(m, dt, K, b, sigma=sigma)
    h = 1e-6
    Jm = np.zeros((3, 40, 3))  # dr / dm_t, by central differences
    for t in range(40):
        for j in range(3):
            up, down = m.copy(), m.copy()
            up[t, 0, j] += h
            down[t, 0, j] -= h
            Jm[:, t, j] = (closure_terms(up, dt, K, b, jacobian=False).r[0] - closure_terms(down, dt, K, b, jacobian=False).r[0]) / (2 * h)
    expected = np.einsum("atj,j,ctj->ac", Jm, sigma[0] ** 2, Jm)
    assert np.allclose(terms.noise[0], expected, rtol=1e-5, atol=1e-14)


# ------------------------------------------------------------------------------------------ the fit


def test_a_turn_about_a_horizontal_axis_ending_short_is_measured():
    """A turn about y stopped 8 deg short leaves the device tilted by 8 deg: the accelerometer sees it, the turn closes
    onto that pose, and k_y is right where, without the placement in the model, it was 1 % off."""
    proto = script(Turn("x", 360.0), Turn("y", 360.0), Turn("z", 360.0), Turn("y", 352.0))
    rec, truth = simulate(110, noise=0.03, script=proto)
    res = calibrate_closure(rec, list(truth.stages))
    short = res.residuals["turns"][3]
    assert short["closure_norm_deg"] == pytest.approx(8.0, abs=0.3) and short["misclosure_norm_deg"] < 0.1
    assert res.quality["placement"]["turns"][3]["tilt_deg"] == pytest.approx(8.0, abs=0.3)
    z, _ = errors(res, truth)
    assert np.all(np.abs(z) < 5.0), z
    assert abs(res.k[1] - truth.k[1]) < 2e-4


def test_noise_free_recording_gives_the_exact_parameters():
    # the simulator closes every turn exactly, so without noise nothing is left to estimate
    rec, truth = simulate(11, noise=0.0)
    res = calibrate_closure(rec, list(truth.stages))
    assert np.max(np.abs(res.k - truth.k)) < 1e-9
    assert np.max(np.abs(res.b - truth.b)) < 1e-7


@pytest.mark.parametrize("noise", [0.03, 0.15])
def test_estimates_lie_within_the_reported_uncertainty(noise):
    for seed in range(20, 28):
        rec, truth = simulate(seed, noise=noise)
        res = calibrate_closure(rec, list(truth.stages), heading_prior_deg=EXACT)
        z, _ = errors(res, truth)
        assert np.all(np.abs(z) < 5.0), (seed, z)
        # the result is at the noise floor: k to a few 1e-5 at 0.03 deg/s, 5x that at 0.15
        assert np.all(res.k_std < 2e-5 * (noise / 0.03) * 1.44 * 1.5)


def test_uncertainty_is_honest_over_a_monte_carlo():
    batch = simulate_batch(7, 300, 0.15)
    k, b, info = closure_batch(batch)
    z = np.concatenate((k - batch.k_true, b - batch.b_true), axis=1) / info["std"]
    assert np.all(np.isfinite(z))
    spread = z.std(axis=0)
    assert np.all((spread > 0.8) & (spread < 1.25)), spread
    assert np.all(np.abs(z.mean(axis=0)) < 0.25), z.mean(axis=0)


def test_single_recording_uncertainty_is_honest_over_a_monte_carlo():
    zs = []
    for seed in range(300, 400):
        rec, truth = simulate(seed, noise=0.03)
        zs.append(errors(calibrate_closure(rec, list(truth.stages), heading_prior_deg=EXACT), truth)[0])
    z = np.array(zs)
    spread = z.std(axis=0)
    assert np.all((spread > 0.75) & (spread < 1.3)), spread  # 100 runs: sampling error of the spread ~0.07
    assert np.all(np.abs(z.mean(axis=0)) < 0.35), z.mean(axis=0)


def test_batch_and_single_recording_estimators_agree():
    batch = simulate_batch(5, 3, 0.03)
    out = closure_fit_batch(batch.gyro, batch.dt, batch.turns, batch.stills)
    for r in range(3):
        run = slice(batch.stills[r, 0, 0], batch.stills[r, -1, 1])
        rec = Recording(batch.t[run], batch.gyro[r, run])
        from calib.stages.stage import Stage

        stages = [Stage("still", int(s), int(e), float(s / FS), float(e / FS)) for s, e in batch.stills[r]]
        stages += [Stage("turn", int(s), int(e), float(s / FS), float(e / FS), "xyz"[j], 360.0) for j, (s, e) in enumerate(batch.turns[r])]
        res = calibrate_closure(rec, stages, heading_prior_deg=EXACT)
        std = np.concatenate((res.k_std, res.b_std))
        assert np.all(np.abs(out["theta"][r] - np.concatenate((res.k, res.b))) < 1e-3 * std)
        assert np.allclose(out["std"][r], std, rtol=1e-3)


@pytest.mark.parametrize("extended", [False, True])
def test_the_fast_fit_lands_where_the_damped_fit_does(extended):
    # Gauss-Newton re-weighted at each step and least_squares re-weighted until the weights settle solve one
    # equation (the gradient at the solution's weights is zero): their answers agree far inside the uncertainty
    from calib.estimators.closure import estimator as closure

    diag_axes = [np.array(v, dtype=float) for v in ((1, 1, 0), (0, 1, 1), (1, 0, 1))]
    proto = script(*(Turn(a, 360.0, 3.5) for a in ("x", "y", "z", *diag_axes)))
    effect = AxisMisalignment(np.array([0.01, -0.008, 0.006]))
    for seed in (40, 41, 42):
        rec, truth = simulate(seed, noise=0.1, script=proto, effects=(effect,))
        used = []
        real_gn = closure._gauss_newton

        def spy(*args, real_gn=real_gn, used=used):
            out = real_gn(*args)
            used.append(out is not None)
            return out

        closure._gauss_newton = spy
        try:
            fast = calibrate_closure(rec, list(truth.stages), extended=extended, heading_prior_deg=EXACT)
            closure._gauss_newton = lambda *args: None  # the damped fit alone
            damped = calibrate_closure(rec, list(truth.stages), extended=extended, heading_prior_deg=EXACT)
        finally:
            closure._gauss_newton = real_gn
        assert used and all(used)  # the fast path took every fit of this recording
        assert np.all(np.abs(fast.k - damped.k) < 1e-2 * damped.k_std)
        assert np.all(np.abs(fast.b - damped.b) < 1e-2 * damped.b_std)
        assert np.allclose(fast.k_std, damped.k_std, rtol=1e-2)
        if extended:
            assert fast.K is not None and damped.K is not None and damped.K_std is not None
            assert np.all(np.abs(fast.K - damped.K)[np.triu_indices(3)] < 1e-2 * damped.K_std[np.triu_indices(3)])


def test_the_extended_models_bound_from_a_diagonal_fits_closure_terms_is_the_one_computed_afresh():
    from calib.estimators.closure.estimator import offdiag_bounds
    from calib.estimators.closure.fit import ClosureData, system
    from calib.noise.rests import still_statistics
    from calib.numerics.windows import windows
    from calib.recording import sample_intervals

    diag_axes = [np.array(v, dtype=float) for v in ((1, 1, 0), (0, 1, 1), (1, 0, 1))]
    rec, truth = simulate(43, noise=0.05, script=script(*(Turn(a, 360.0, 3.5) for a in ("x", "y", "z", *diag_axes))))
    turns = [s for s in truth.stages if s.kind == "turn"]
    stills = [s for s in truth.stages if s.kind == "still"]
    m, d = windows(rec.gyro[None], np.array([[[s.start, s.end] for s in turns]]), sample_intervals(rec.t)[None])
    mean, count, sigma = still_statistics(rec.gyro[None], np.array([[[s.start, s.end] for s in stills]]))
    data = ClosureData(m, d, mean, count, sigma)
    theta = np.concatenate((truth.k, truth.b, np.zeros(3)))
    terms = system(data, theta[None, :6], False).terms
    assert np.allclose(offdiag_bounds(data, theta, terms), offdiag_bounds(data, theta), rtol=1e-12)


def test_bound_is_the_closed_form_cramer_rao_bound_on_the_paper_protocol():
    for seed in (40, 41, 42):
        rec, truth = simulate(seed, noise=0.03)
        res = calibrate_closure(rec, list(truth.stages), heading_prior_deg=EXACT)
        turns = [s for s in truth.stages if s.kind == "turn"]
        sk, sb = protocol_bound(res.noise_dps, FS, [s.duration_s for s in turns], res.quality["still_s"], truth.k, truth.b)
        assert np.allclose(res.k_bound, sk, rtol=0.05)
        # the turns add a little bias information of their own, across axes
        assert np.all(res.b_bound <= sb * 1.01) and np.all(res.b_bound > 0.85 * sb)
        # with k = 1 the closed form is the textbook one
        sk1, sb1 = protocol_bound(0.03, FS, 4.0, 12.0)
        assert sk1 == pytest.approx(0.03 / 360 * np.sqrt(4.0 / FS) * np.sqrt(1 + 4.0 / 12.0))
        assert sb1 == pytest.approx(0.03 / np.sqrt(FS * 12.0))


def test_reported_std_is_the_bound_scaled_by_the_birge_ratio():
    rec, truth = simulate(50, noise=0.03)
    res = calibrate_closure(rec, list(truth.stages), heading_prior_deg=0.1)  # a stated heading spread
    birge = max(1.0, np.sqrt(res.quality["chi2"] / res.quality["dof"]))
    assert res.quality["birge_ratio"] == pytest.approx(birge)
    assert np.allclose(res.k_std, res.k_bound * birge) and np.allclose(res.b_std, res.b_bound * birge)
    assert res.quality["dof"] == 3 * 3 + 3 * 4 - 6
    assert res.k_dof is None and res.quality["placement"]["heading"]["source"] == "stated"
    # learned from the turns (about x and y, and z against them), the spread is one parameter more
    learned = calibrate_closure(rec, list(truth.stages))
    heading = learned.quality["placement"]["heading"]
    assert heading["source"] == "estimated" and heading["turns"] == 3
    assert learned.quality["dof"] == 3 * 3 + 3 * 4 - 6 - 1 and learned.k_dof is not None


def test_default_method_is_closure_with_detected_stages():
    rec, truth = simulate(60, noise=0.03)
    res = calibrate(rec)
    assert res.method == "closure"
    z, _ = errors(res, truth)
    assert np.all(np.abs(z) < 5.0)
    assert [s.kind for s in res.stages] == ["still", "turn", "still", "turn", "still", "turn", "still"]


# ------------------------------------------------------------------------------------------ other protocols


def test_any_number_of_turns_in_either_direction_about_any_axis():
    params = SensorParams(np.array([0.9, 1.1, 1.05]), np.array([2.0, -1.0, 3.5]))
    base = script(Turn("x", 360.0, 3.5), Turn("y", 360.0, 3.5), Turn("z", 360.0, 3.5))
    more = script(
        Turn("x", -360.0, 3.5),
        Turn("y", 360.0, 3.5),
        Turn("y", -360.0, 3.5),
        Turn("z", 360.0, 3.5),
        Turn(np.array([1.0, 1.0, 1.0]), 360.0, 4.0),
    )
    rec0, truth0 = simulate(70, noise=0.05, params=params, script=base)
    rec1, truth1 = simulate(71, noise=0.05, params=params, script=more)
    res0 = calibrate_closure(rec0, list(truth0.stages))
    res1 = calibrate_closure(rec1, list(truth1.stages))
    assert len(res1.residuals["turns"]) == 5
    assert res1.residuals["turns"][0]["angle_deg"] < 0 < res1.residuals["turns"][1]["angle_deg"]
    for res, truth in ((res0, truth0), (res1, truth1)):
        assert np.all(np.abs(errors(res, truth)[0]) < 5.0)
    assert res1.k_bound[1] < res0.k_bound[1] / 1.2  # the second turn about y adds information


def test_a_turn_of_two_revolutions_closes_on_its_own_branch():
    rec, truth = simulate(80, noise=0.03, script=script(Turn("x", 360.0), Turn("y", 360.0), Turn("z", 720.0, 6.0)))
    res = calibrate_closure(rec, list(truth.stages))
    assert [t["revolutions"] for t in res.residuals["turns"]] == [1, 1, 2]
    assert np.all(np.abs(errors(res, truth)[0]) < 5.0)


def test_extended_model_recovers_non_orthogonality_from_turns_about_diagonal_axes():
    params = SensorParams(np.array([1.05, 0.95, 1.1]), np.array([1.0, -2.0, 0.5]))
    effect = AxisMisalignment(np.array([0.01, -0.008, 0.006]))  # K_xy, K_xz, K_yz
    diag_axes = [np.array(v, dtype=float) for v in ((1, 1, 0), (0, 1, 1), (1, 0, 1))]
    proto = script(*(Turn(a, 360.0, 3.5) for a in ("x", "y", "z", *diag_axes)))
    K_true = effect.matrix(params.k)
    upper = np.triu_indices(3)
    for seed in (90, 91, 92):
        rec, truth = simulate(seed, noise=0.03, params=params, script=proto, effects=(effect,))
        res = calibrate_closure(rec, list(truth.stages), extended=True, heading_prior_deg=EXACT)
        assert res.K is not None and res.K_std is not None
        z = (res.K - K_true)[upper] / res.K_std[upper]
        assert np.all(np.abs(z) < 5.0), z
        assert np.all(np.abs((res.b - params.b) / res.b_std) < 5.0)
        assert np.all(res.K_std[[0, 0, 1], [1, 2, 2]] < 1e-4)
        # the diagonal model cannot explain these data
        diag = calibrate_closure(rec, list(truth.stages), extended=False, heading_prior_deg=EXACT)
        assert diag.quality["p_value"] < 1e-6 and any("worse than the noise" in w for w in diag.warnings)
        # left to choose, the estimator takes the extended model: identified here, and needed
        auto = calibrate_closure(rec, list(truth.stages), heading_prior_deg=EXACT)
        assert auto.K is not None and "significant" in auto.quality["model_choice"]["reason"]
        assert np.allclose(auto.K, res.K)


def test_the_extended_model_is_not_chosen_where_the_turns_leave_it_free_or_it_is_not_needed():
    rec, truth = simulate(95, noise=0.03, script=script(*(Turn(a, 360.0, 3.5, wobble_deg=0.0, tilt=0) for a in "xyz")))
    res = calibrate_closure(rec, list(truth.stages))
    assert res.K is None and "not identified" in res.quality["model_choice"]["reason"]
    diag_axes = [np.array(v, dtype=float) for v in ((1, 1, 0), (0, 1, 1), (1, 0, 1))]
    proto = script(*(Turn(a, 360.0, 3.5) for a in ("x", "y", "z", *diag_axes)))
    chosen = 0
    for seed in range(10):
        rec, truth = simulate(200 + seed, noise=0.03, script=proto)  # orthogonal axes
        res = calibrate_closure(rec, list(truth.stages))
        assert res.quality["model_choice"]["p_value"] is not None
        chosen += res.K is not None
    assert chosen <= 2  # a 1 % test: rarely taken when the axes are orthogonal


def test_extended_model_refuses_when_the_turns_cannot_identify_it():
    # turns about fixed sensor axes close for any off-diagonal terms: nothing to estimate them from
    proto = script(*(Turn(a, 360.0, 3.5, wobble_deg=0.0, tilt=0) for a in "xyz"))
    rec, truth = simulate(95, noise=0.03, script=proto)
    with pytest.raises(CalibrationError, match="non-orthogonality"):
        calibrate_closure(rec, list(truth.stages), extended=True)


def test_a_prior_on_the_non_orthogonality_is_weighed_with_what_the_turns_show_of_it():
    params = SensorParams(np.array([1.05, 0.95, 1.1]), np.array([1.0, -2.0, 0.5]))
    effect = AxisMisalignment(np.array([0.01, -0.008, 0.006]))  # K_xy, K_xz, K_yz
    K_true = effect.matrix(params.k)
    off = ([0, 0, 1], [1, 2, 2])
    # turns about fixed sensor axes show nothing of the terms: the prior is all there is, and k is fitted with it
    rec, truth = simulate(95, noise=0.03, params=params, script=script(*(Turn(a, 360.0, 3.5, wobble_deg=0.0, tilt=0)
                                                                          for a in "xyz")), effects=(effect,))
    prior_std = np.full(3, 0.002)
    mean, std = np.diag(params.k), np.full((3, 3), np.inf)
    mean[off], std[off] = K_true[off] + 0.001, prior_std
    res = calibrate_closure(rec, list(truth.stages), heading_prior_deg=EXACT, k_prior=KPrior(mean, std))
    assert res.K is not None and res.K_std is not None and res.quality["model"] == "upper-triangular"
    assert "known of K" in res.quality["model_choice"]["reason"]
    assert np.allclose(res.K[off], K_true[off] + 0.001, atol=3e-4)
    assert np.allclose(res.K_std[off], prior_std, rtol=0.2)
    # turns that identify the terms outweigh a loose prior centred on zero
    diag_axes = [np.array(v, dtype=float) for v in ((1, 1, 0), (0, 1, 1), (1, 0, 1))]
    rec, truth = simulate(90, noise=0.03, params=params, script=script(*(Turn(a, 360.0, 3.5)
                                                                          for a in ("x", "y", "z", *diag_axes))),
                          effects=(effect,))
    std = np.full((3, 3), np.inf)
    std[off] = 0.02
    res = calibrate_closure(rec, list(truth.stages), heading_prior_deg=EXACT, k_prior=KPrior(np.eye(3), std))
    assert res.K is not None and res.K_std is not None
    z = (res.K - K_true)[off] / res.K_std[off]
    assert np.all(np.abs(z) < 5.0) and np.all(res.K_std[off] < 1e-4), z
    assert np.all(np.abs((res.k - params.k) / res.k_std) < 5.0)


# ------------------------------------------------------------------------------------------ the result


def test_result_carries_parameters_uncertainty_bound_and_residuals():
    rec, truth = simulate(100, noise=0.03)
    res = calibrate_closure(rec, list(truth.stages))
    d = json.loads(json.dumps(res.to_dict()))
    assert d["method"] == "closure"
    assert len(d["uncertainty"]["k"]) == 3 and len(d["bound"]["b"]) == 3
    assert d["noise_dps"] == pytest.approx([0.03] * 3, rel=0.1)
    turns, stills = d["residuals"]["turns"], d["residuals"]["stills"]
    assert [t["axis"] for t in turns] == ["x", "y", "z"] and len(stills) == 4
    for t in turns:
        assert t["closure_norm_deg"] < 6 * t["closure_std_deg"]
        assert d["stages"][t["stage"]]["kind"] == "turn"
    for s in stills:
        assert np.all(np.abs(s["rate_dps"]) < 0.01)
    assert sorted(d["quality"]["stages_used"]) == list(range(7))
    assert d["warnings"] == []


def test_a_turn_that_does_not_come_back_is_reported():
    # a short turn alone would only bias its axis's k; a second turn about the same axis exposes it. It is about the
    # vertical, where the accelerometer cannot see that it stopped short (a short turn about a horizontal axis ends
    # tilted: the accelerometer measures that, see test_a_turn_about_a_horizontal_axis_ending_short_is_measured)
    proto = script(Turn("x", 360.0), Turn("y", 360.0), Turn("z", 360.0), Turn("z", 352.0))
    rec, truth = simulate(110, noise=0.03, script=proto)
    res = calibrate_closure(rec, list(truth.stages))
    z_turns = [t for t in res.residuals["turns"] if t["axis"] == "z"]
    assert all(t["misclosure_norm_deg"] > 2.0 for t in z_turns)
    assert sum("about z" in w and "against the block" in w for w in res.warnings) == 2
    assert any("worse than the noise" in w for w in res.warnings)
    assert res.quality["birge_ratio"] > 10 and np.all(res.k_std > 10 * res.k_bound)


# ------------------------------------------------------------------------------------------ bad input


def test_a_missing_turn_leaves_its_axis_undetermined_and_the_others_calibrated():
    rec, truth = simulate(120, noise=0.03, script=script(Turn("x", 360.0), Turn("y", 360.0)))
    for stages in (None, list(truth.stages)):  # detected, or given without a turn about z
        res = calibrate_closure(rec, stages)
        assert res.quality["undetermined_axes"] == ["z"] and np.isnan(res.k[2]) and np.isnan(res.b[2])
        assert np.all(np.abs(res.k[:2] - truth.k[:2]) < 5 * res.k_std[:2])
        assert any(w.startswith("no usable full turn about z") for w in res.warnings)
    # no turn at all is still refused
    still, _ = simulate(120, noise=0.03, script=ProtocolScript((Still(3.0), Still(3.0))))
    with pytest.raises(ProtocolError):
        calibrate_closure(still)


def test_bad_input_is_a_recording_error():
    rec, _ = simulate(121, noise=0.03)
    with pytest.raises(RecordingError):
        calibrate_closure("not a recording")
    gyro = rec.gyro.copy()
    gyro[100, 1] = np.nan
    with pytest.raises(RecordingError, match="NaN"):
        calibrate_closure(Recording(rec.t, gyro))


# ------------------------------------------------------------------------------------------ real data


def test_imucal_session_matches_imucal_with_stages_found_automatically(ferraris_csv):
    rec = read_recording(ferraris_csv, fs=102.4)
    res = calibrate_closure(rec)
    assert [t["axis"] for t in res.residuals["turns"]] == ["x", "y", "z"]
    assert all(t["angle_deg"] < -355 for t in res.residuals["turns"])  # clockwise turns
    assert np.all(np.abs(res.k - IMUCAL_K) < 5e-4), res.k - IMUCAL_K
    assert np.all(np.abs(res.b - IMUCAL_B) < 0.01), res.b - IMUCAL_B
    # the offset moves between the six poses (see the data README): the fit says so and widens its errors
    assert res.quality["birge_ratio"] > 1.5
    assert np.all(res.k_std > res.k_bound)
    with pytest.raises(CalibrationError, match="non-orthogonality"):
        calibrate_closure(rec, res.stages, extended=True)


# ------------------------------------------------------------------------------------------ the benchmark


def test_paper_sim_shows_closure_beside_the_paper_and_the_bound():
    from calib.studies.paper_sim import paper_sim

    report = paper_sim(sets=1, runs_per_set=60, noise_levels=(0.15,), methods=("paper", "closure"), workers=1, progress=False)
    closure = report.stats("closure", 0.15)["params"]
    for name in ("kx", "by"):
        assert 0.7 < closure[name]["z_sd"] < 1.35
        # an efficient estimator: |err| p95 near the Cramer-Rao bound's, which the paper's method does not reach
        assert closure[name]["abs_p95"] < 1.6 * closure[name]["bound_abs_p95"]
    assert report.stats("paper", 0.15)["params"]["bx"]["abs_p95"] > 1.6 * closure["bx"]["bound_abs_p95"]
    table = report.table()
    assert "bound" in table and "closure err/std sd" in table


def test_still_statistics_pool_each_still_about_its_own_mean():
    from calib.noise.rests import still_statistics

    rng = np.random.default_rng(12)
    gyro = rng.normal(0.0, 0.1, (3, 200, 3)) + np.array([2.0, -1.0, 0.5])
    gyro[:, 100:] += 0.3  # the offset moves between stills: it must not count as noise
    ordered = np.array([[[0, 20], [30, 50], [50, 50], [120, 200]]] * 3)
    unordered = ordered.copy()
    unordered[1] = [[120, 200], [0, 20], [30, 50], [60, 61]]
    for bounds in (ordered, unordered):  # one-pass sums, and running sums for unordered windows
        mean, count, sigma = still_statistics(gyro, bounds)
        for r in range(3):
            segs = [gyro[r, s:e] for s, e in bounds[r] if e > s]
            assert np.allclose(mean[r][count[r] > 0], [seg.mean(axis=0) for seg in segs])
            ss = sum(((seg - seg.mean(axis=0)) ** 2).sum(axis=0) for seg in segs)
            assert np.allclose(sigma[r], np.sqrt(ss / sum(len(seg) - 1 for seg in segs)))
        assert np.array_equal(count[0], [20, 20, 0, 80])


def test_saturated_turns_are_left_out_and_said_so():
    rec, truth = simulate(130, noise=0.03, full_scale_dps=150.0)
    saturated = [s for s in truth.stages if "saturated" in s.flags]
    assert [s.axis for s in saturated] == ["z"], "the simulated turn about z should exceed 150 deg/s"
    res = calibrate_closure(rec, list(truth.stages))
    assert res.quality["undetermined_axes"] == ["z"] and [t["axis"] for t in res.residuals["turns"]] == ["x", "y"]
    assert any("about z" in w and "full scale" in w for w in res.warnings)


def test_a_turn_that_ends_in_another_pose_is_refused():
    from calib.simulator import Motion
    from calib.stages.stage import Stage

    proto = ProtocolScript((Still(3.0), Turn("x", 360.0), Still(3.0), Turn("y", 360.0), Motion((60.0, 0.0, 0.0), 1.5),
                            Still(3.0), Turn("z", 360.0), Still(3.0)))
    rec, truth = simulate(140, noise=0.03, script=proto)
    st = list(truth.stages)
    y, motion = st[3], st[4]
    merged = Stage("turn", y.start, motion.end, y.start_s, motion.end_s, "y", 360.0)  # the hand never came back
    with pytest.raises(CalibrationError, match="about y"):
        calibrate_closure(rec, st[:3] + [merged] + st[5:])


def test_a_result_round_trips_through_its_dict() -> None:
    from calib.pipeline import calibrate
    from calib.result import CalibrationResult
    from calib.simulator import simulate

    rec, _ = simulate(5, noise=0.03)
    for result in (calibrate(rec), calibrate(rec, method="paper")):
        back = CalibrationResult.from_dict(result.to_dict())
        assert back.to_dict() == result.to_dict()
        np.testing.assert_allclose(Correction.from_result(back).apply(rec.gyro)[0], Correction.from_result(result).apply(rec.gyro)[0],
                                   atol=1e-6)
