"""``diagnose``: compare a recording with what the simulator predicts for it, and explain the difference."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from calib.diagnosis.assemble import Diagnosis, assemble_diagnosis
from calib.diagnosis.data import Problem, build_problem, gravity_proxy, make_layout, set_design_accel
from calib.diagnosis.engine import Priors, system
from calib.diagnosis.extended_fits import ModelState, gm_of, informative_count
from calib.diagnosis.features import SIGNED, compute_features
from calib.diagnosis.fitting import fit_nominal
from calib.diagnosis.gauss_newton import Fit, gauss_newton
from calib.diagnosis.models import Model
from calib.diagnosis.null import Replay, make_replay, replicate_problems, with_effects
from calib.diagnosis.reorientation import prepare as prepare_reorientations
from calib.diagnosis.rivals import Worlds
from calib.diagnosis.saturation import plateau_caps
from calib.diagnosis.select import ALPHA, Candidate, null_fit, p_value, plan_tests, statistics
from calib.diagnosis.stepwise import select_effects
from calib.diagnosis.timebase import TimeBase, analyse_timebase, bridge, on_bridged_rows
from calib.distributions import norm_sf
from calib.effects import CATALOGUE
from calib.errors import GyrocalError, ProtocolError, RecordingError, RecordingTooLong
from calib.io.section import Section
from calib.numerics.gram import gram
from calib.pipeline import pointing_to, protocol_stages
from calib.recording import Recording
from calib.stages.plateaus import Plateau, find_plateaus
from calib.stages.resolve import resolve_stages
from calib.stages.stage import AXES, Stage
from calib.stages.turn_checks import angle_between_deg

DEFAULT_MAX_SAMPLES = 500_000
MEMORY_PER_SAMPLE_KB = 13.0  # peak memory of a diagnosis grows by about this per sample (measured, bench/diagnosis_memory.py)

EFFECT_NAMES: tuple[str, ...] = CATALOGUE  # the catalogue, in the order the documentation lists it
DEFAULT_BOOT = 200
CHUNK = 50  # replicates simulated and fitted at once

Progress = Callable[[float, str], None]


# --------------------------------------------------------------------------- entry point


def diagnose(
    rec: Recording,
    progress: Progress | None = None,
    n_boot: int = DEFAULT_BOOT,
    seed: int = 0,
    host_t: np.ndarray | None = None,
    stages: list[Stage] | None = None,
    max_samples: int | None = DEFAULT_MAX_SAMPLES,
    protocol: str = "auto",
    sections: tuple[Section, ...] | None = None,
) -> Diagnosis:
    """Diagnose a recording of the protocol against the nominal model g = K m + b.

    The constraints are those ``calib.pipeline.calibrate_protocol`` calibrates with: ``protocol`` "auto" (what the
    recording holds), "paper", "ferraris" (rests and full turns) or "multi-position" (rests and the gravity each
    re-orientation carries, with the accelerometer calibrated first); ``sections`` (or the recording's own)
    replace stage detection, as do ``stages``.

    ``max_samples``: refuse (RecordingTooLong) a recording that has, or would have once its lost samples are
    put back, more samples than this; the work and memory grow with them (about 13 kB a sample).

    ``n_boot`` simulated replicates give the null distribution (deterministic by ``seed``).
    ``host_t`` (n,): the time each sample reached the host (default: the recording's ``host_t`` channel);
    against the device's counter it reveals a sample-clock error.
    ``progress(fraction, stage)`` is called as the work advances.
    """
    t_start = time.perf_counter()
    say = progress or (lambda f, s: None)
    _check(rec, host_t, n_boot)
    if host_t is None:
        host_t = getattr(rec, "host_t", None)
    say(0.0, "stages")
    tb = analyse_timebase(rec, host_t)
    _check_size(rec, tb, max_samples)
    # the stages are those calibrate finds, on the delivered rows: a gap is a gap to the detector, where samples put
    # back would be noiseless and lower its noise floor, and a motion the link lost is not a turn to use
    stages, found, used = protocol_stages(rec, protocol, sections, stages)
    raw = None
    if tb.lost > 0 and tb.index_source is not None:
        # lost samples are put back at their sample numbers; the analysis runs on the bridged recording
        if host_t is not None:
            rec = replace(rec, host_t=np.asarray(host_t, dtype=float))
        raw = rec
        rec = bridge(rec, tb)
        host_t = rec.host_t
        stages = [on_bridged_rows(s, tb) for s in stages]
    plateaus = find_plateaus(rec)
    moving = None
    if used == "multi-position":
        moving = prepare_reorientations(rec, stages)
        rec, stages = moving.rec, moving.stages
    else:
        stages = _clipped_turns(rec, list(stages), plateaus)
        try:
            stages = resolve_stages(rec, stages).stages  # a ProtocolError naming the missing stage, as calibrate gives
        except ProtocolError as exc:
            raise pointing_to(exc, used, found, "diagnose") from None  # ... and the protocol the recording holds instead
    if raw is None:
        dt = _intervals(rec, tb)
    else:
        lost_tb = tb
        tb = analyse_timebase(rec, host_t)
        dt = _intervals(rec, tb)
        tb = _merge_timebase(lost_tb, tb)
    layout = make_layout(rec, stages, dt)
    if moving is not None:
        layout = moving.with_references(layout)
    caps = plateau_caps(len(rec), rec.t, plateaus) if plateaus else None
    temp = rec.temp - rec.temp[0] if rec.temp is not None else None
    accel = rec.accel
    prob = build_problem(layout, rec.gyro[None], None if accel is None else accel[None], temp, caps)
    say(0.05, "nominal fit")

    # a clipped turn's closure, or a clipped re-orientation's gravity, is left free: it reads short by what was clipped
    clipped = tuple(j for j, s in enumerate(layout.turns) if any(s.start <= p.start < s.end for p in plateaus))
    start = _unclipped_start(rec, layout, clipped, accel, temp) if clipped else None
    if start is None and moving is not None:
        start = moving.start
    fit0 = fit_nominal(prob, start)
    start = fit0.psi if start is None else start
    a_design = None
    if accel is None:
        # no accelerometer: gravity as the protocol leaves it, the device resting flat, followed through the turns
        a_design = gravity_proxy(layout, rec.gyro * start[0, :3] + start[0, 3:6])
        set_design_accel(prob, a_design)
    base = Model(("saturation",) if clipped else (), layout.J, tuple(p.axis for p in plateaus), clipped)
    priors = None
    cap_fit = None
    base_fit = fit0
    if clipped:
        # the clipped turns' closures are left free; a scale factor no unclipped turn fixes comes from the
        # plateaus rebuilt from their edges, as a prior with that reconstruction's uncertainty
        cap_model = Model(("plateau",), layout.J, tuple(p.axis for p in plateaus))
        cap_fit = (cap_model, gauss_newton(prob, cap_model, cap_model.zeros(start),
                                           priors=_plateau_priors(plateaus, cap_model), max_iter=10))
        priors = _clipped_axis_priors(layout, clipped, cap_fit[1])
        base_fit = gauss_newton(prob, base, base.zeros(cap_fit[1].psi[:, :6]), priors=priors, max_iter=10)
    duration = float(rec.t[-1] - rec.t[0])
    temp_range = float(np.ptp(temp)) if temp is not None else 0.0
    specs, union, not_ident = plan_tests(prob, base, base_fit, priors, accel is not None, temp is not None, duration,
                                         temp_range)
    obs_stats, sys_obs = statistics(prob, union, base, base_fit.psi, specs, priors)
    feats = compute_features(prob, sys_obs, base_fit.psi)

    # ---- the null: the recording simulated from its base fit, many times
    say(0.1, "simulating the recording")
    full_scale = float(np.mean([p.level for p in plateaus])) if plateaus else None
    replay = make_replay(layout, rec.gyro, accel, temp, base, base_fit.psi[0], prob.sigma[0],
                         None if prob.accel_sigma is None else prob.accel_sigma[0], caps, full_scale)
    rng = np.random.default_rng(seed)
    boot_stats, boot_feats = _bootstrap(replay, base, base_fit.psi, priors, union, specs, n_boot, rng, caps, a_design,
                                        lambda f: say(0.1 + 0.55 * f, "simulating the recording"))

    # ---- tests
    say(0.7, "testing effects")
    m = max(1, len(specs))
    alpha = ALPHA / m
    cands: list[Candidate] = []
    tests: dict[str, dict] = {}
    for s in specs:
        null = null_fit(boot_stats[s.key])
        p = p_value(float(obs_stats[s.key][0]), null)
        tests[s.key] = {"name": s.name, "statistic": float(obs_stats[s.key][0]), "p_value": p, "null": null,
                        "noncentrality": s.noncentrality}
        if p < alpha:
            cands.append(Candidate(s.name, s.key, float(obs_stats[s.key][0]), p, s.dof, null, s.noncentrality))

    # ---- selection
    say(0.75, "fitting extended models")
    n_info = informative_count(prob, accel is not None)
    pen = float(np.log(n_info))
    state = ModelState(base, base_fit, priors, {}, ())
    sims = [0]

    def simulated(what: str) -> None:
        # the number of rival simulations is not known ahead: the bar approaches the next stage, never reaching it
        sims[0] += 1
        say(0.75 + 0.1 * (1.0 - 0.97 ** sims[0]), f"fitting extended models: {what} ({sims[0]} simulations)")

    worlds = Worlds(replay, state, priors, pen, caps, a_design, seed, simulated)
    steps, ambiguities = select_effects(prob, state, cands, specs, priors, alpha, pen, worlds)
    final = steps[-1][1] if steps else state

    # ---- what the recording looks like next to a simulation with the effects
    say(0.85, "checking the fitted model against simulation")
    p_before = _feature_p(feats.values[0], boot_feats, feats.kinds)
    p_after = None
    if steps:
        replay_fx = with_effects(replay, final.model, final.fit.psi[0], gm_of(final), a_design)
        _, feats_after = _bootstrap(replay_fx, base, base_fit.psi, priors, union, [], max(50, n_boot // 2),
                                    np.random.default_rng(seed + 1), caps, a_design,
                                    lambda f: say(0.85 + 0.1 * f, "checking the fitted model against simulation"))
        p_after = _feature_p(feats.values[0], feats_after, feats.kinds)
        boot_feats_after = feats_after
    else:
        boot_feats_after = None

    say(0.95, "report")
    diag = assemble_diagnosis(rec, raw, host_t, prob, layout, tb, plateaus, fit0, base, base_fit, cap_fit, steps, ambiguities, final, feats,
                     boot_feats, boot_feats_after, p_before, p_after, tests, not_ident, specs, alpha, n_boot, duration)
    diag.info["protocol"] = {"found": found.to_dict(), "used": used}
    if moving is not None:
        diag.info["accelerometer"] = moving.accel.to_dict()
    diag.info["seconds"] = round(time.perf_counter() - t_start, 3)
    say(1.0, "done")
    return diag


def _check_size(rec: Recording, tb: TimeBase, max_samples: int | None) -> None:
    n = len(rec)
    if tb.lost > 0 and tb.index_source is not None:
        n = int(tb.index[-1] - tb.index[0]) + 1
    if max_samples is None or n <= max_samples:
        return
    span = float(rec.t[-1] - rec.t[0])
    bridged = (f" once the {n - len(rec)} samples its {tb.index_source} says are missing are put back (it spans {span:.0f} s)"
               if n > len(rec) else "")
    raise RecordingTooLong(
        f"the recording would be diagnosed as {n} samples{bridged}, about {MEMORY_PER_SAMPLE_KB * n / 1e6:.1f} GB of work; "
        f"at most {max_samples} are diagnosed. Send the protocol's part of the recording (about 30-90 s), and check its "
        "time stamps or counter if it should be shorter"
    )


def _check(rec: Recording, host_t: np.ndarray | None, n_boot: int) -> None:
    if not isinstance(rec, Recording):
        raise RecordingError(f"expected a Recording, got {type(rec).__name__}: read files with calib.io.readers.read_recording")
    if len(rec) < 10:
        raise RecordingError(f"the recording has {len(rec)} samples: record the full protocol (about 30 s)")
    if not np.all(np.isfinite(rec.gyro)) or not np.all(np.isfinite(rec.t)):
        raise RecordingError("the recording contains NaN or infinite values: remove or repair those samples")
    if np.any(np.diff(rec.t) <= 0):
        raise RecordingError("sample times must increase strictly: sort the samples and remove duplicates")
    if host_t is not None and np.shape(host_t) != rec.t.shape:
        raise RecordingError(f"host_t must give one host time per sample ({rec.t.size}); got shape {np.shape(host_t)}")
    if not isinstance(n_boot, (int, np.integer)) or n_boot < 20:
        raise RecordingError(f"n_boot must be a whole number of at least 20 simulated replicates; got {n_boot!r}")


def _unclipped_start(rec: Recording, layout, clipped: tuple[int, ...], accel, temp) -> np.ndarray | None:
    """Nominal parameters from the unclipped turns alone (None when some axis has no unclipped turn): a
    clipped turn reads short and would pull the scale factors far off."""
    drop = {id(layout.turns[j]) for j in clipped}
    stages = [s for s in layout.stages if id(s) not in drop]
    sub = make_layout(rec, stages, layout.dt)
    if {s.axis for s in sub.turns} != set(AXES):
        return None
    p = build_problem(sub, rec.gyro[None], None if accel is None else accel[None], temp)
    try:
        return fit_nominal(p).psi
    except GyrocalError:
        return None


def _merge_timebase(lost: TimeBase, bridged: TimeBase) -> TimeBase:
    """The time base of the recording as delivered (its gaps), with the clock found on the bridged one."""
    lost.clock_e, lost.clock_std, lost.clock_fit, lost.host = bridged.clock_e, bridged.clock_std, bridged.clock_fit, bridged.host
    return lost


def _intervals(rec: Recording, tb: TimeBase) -> np.ndarray:
    """Sample intervals: from the device's counter when the timestamps are host arrival times, else from t."""
    if tb.index_source == "counter" and not tb.device_stamps:
        period = tb.period / (1.0 + tb.clock_e) if tb.clock_e is not None else tb.period
        d = np.diff(tb.index).astype(float) * period
        return np.append(d, period)
    return rec.intervals_s


FULL_TURN_POSE_DEG = 15.0  # a full turn puts the device back within this of its pose (an accelerometer's word)


def _pose_changed(rec: Recording, before: Stage, after: Stage) -> bool:
    """Whether gravity points elsewhere in the rest after a motion than in the one before (a re-orientation, such as
    a flip between Ferraris' static poses, not a full turn); False without an accelerometer."""
    if rec.accel is None:
        return False
    g0, g1 = rec.accel[before.start:before.end].mean(axis=0), rec.accel[after.start:after.end].mean(axis=0)
    return angle_between_deg(g0, g1) > FULL_TURN_POSE_DEG


def _clipped_turns(rec: Recording, stages: list[Stage], plateaus: list[Plateau]) -> list[Stage]:
    """A motion between two stills that holds clipped readings is a turn that read short: label it one."""
    if not plateaus:
        return stages
    out = list(stages)
    for i, s in enumerate(out):
        if s.kind != "motion" or i == 0 or i == len(out) - 1:
            continue
        if out[i - 1].kind != "still" or out[i + 1].kind != "still":
            continue
        inside = [p for p in plateaus if s.start <= p.start < s.end]
        if not inside or _pose_changed(rec, out[i - 1], out[i + 1]):
            continue
        axis = AXES[max(inside, key=lambda p: p.n).axis]
        sign = float(np.sign(np.median([p.sign for p in inside if AXES[p.axis] == axis])))
        out[i] = Stage("turn", s.start, s.end, s.start_s, s.end_s, axis, 360.0 * sign, tuple(sorted(set(s.flags) | {"saturated"})))
    return out


def _clipped_axis_priors(layout, clipped: tuple[int, ...], cap_fit: Fit) -> Priors | None:
    """Prior on each scale factor whose every turn was clipped: the value the rebuilt plateaus give."""
    from calib.diagnosis.describe import std_of

    axes = []
    for ax, name in enumerate(AXES):
        turns = [j for j, s in enumerate(layout.turns) if s.axis == name]
        if turns and set(turns) <= set(clipped):
            axes.append(ax)
    if not axes:
        return None
    std = std_of(cap_fit)
    k = cap_fit.psi[0, axes]
    sd = np.maximum(std[axes], 2e-3 * np.abs(k))
    return Priors(np.array(axes), k[None, :], sd[None, :])


def _plateau_priors(plateaus: list[Plateau], model: Model) -> Priors:
    s = model.slices["plateau"].start
    C = len(plateaus)
    return Priors(np.arange(s, s + C), np.array([[p.height for p in plateaus]]), np.array([[p.height_sd for p in plateaus]]))


# --------------------------------------------------------------------------- bootstrap


def _one_step(prob: Problem, model: Model, psi: np.ndarray, priors: Priors | None) -> np.ndarray:
    """One Gauss-Newton step from psi (the replicates start at their true parameters)."""
    from calib.diagnosis.gauss_newton import pinv_solve

    sys_ = system(prob, model, psi, priors)
    A = gram(sys_.J)
    g = np.einsum("rmp,rm->rp", sys_.J, sys_.res)
    step, _ = pinv_solve(A, -g)
    return psi + step


def _bootstrap(replay: Replay, base: Model, psi_base: np.ndarray, priors: Priors | None, union: Model, specs, n: int,
               rng: np.random.Generator, caps, a_design, tick) -> tuple[dict[str, np.ndarray], np.ndarray]:
    stats: dict[str, list[np.ndarray]] = {s.key: [] for s in specs}
    feats: list[np.ndarray] = []
    done = 0
    while done < n:
        R = min(CHUNK, n - done)
        prob = replicate_problems(replay, rng, R, caps, a_design)
        pri = None
        if priors is not None:
            pri = Priors(priors.idx, np.repeat(priors.target, R, axis=0), np.repeat(priors.sd, R, axis=0))
        psi = _one_step(prob, base, np.repeat(psi_base, R, axis=0), pri)
        if specs:
            st, sys_ = statistics(prob, union, base, psi, specs, priors)
            for k, v in st.items():
                stats[k].append(v)
        else:  # features only: the residuals are the base model's (every effect at zero), without the union's Jacobian
            sys_ = system(prob, base, psi, pri)
        feats.append(compute_features(prob, sys_, psi).values)
        done += R
        tick(done / n)
    return {k: np.concatenate(v) for k, v in stats.items()}, np.concatenate(feats)


def _feature_p(obs: np.ndarray, boot: np.ndarray, kinds: list[str]) -> np.ndarray:
    """p-values of observed features against bootstrap samples: Gaussian tails for signed features,
    scaled chi-square tails for non-negative ones."""
    p = np.ones(obs.size)
    for i in range(obs.size):
        b = boot[:, i]
        b = b[np.isfinite(b)]
        if b.size < 5:
            continue
        if kinds[i] == SIGNED:
            sd = float(b.std(ddof=1))
            z = (obs[i] - float(b.mean())) / max(sd, 1e-300)
            p[i] = float(2.0 * norm_sf(abs(z)))
        else:
            p[i] = p_value(float(obs[i]), null_fit(b))
    return p


# --------------------------------------------------------------------------- selection


# --------------------------------------------------------------------------- output


