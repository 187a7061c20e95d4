"""Forward selection of effects: at each step the effect that improves the fit most by the information criterion,
set aside or named against its close rivals by Cox's test (calib.diagnosis.rivals)."""

from __future__ import annotations

from calib.diagnosis.data import Problem
from calib.diagnosis.extended_fits import ModelState, criterion, press, try_fit
from calib.diagnosis.rivals import Worlds, rival_test
from calib.diagnosis.select import Candidate, Step
from calib.distributions import chi2_sf

AMBIGUOUS_IC = 4.0  # a rival this close in the information criterion needs Cox's test to be set aside


# effects Cox's test leaves alone. With the accelerometer, the replay puts the device back exactly, so the tilts it
# measured (which scale the placement model's heading prior) are not reproduced and the world would not be like the
# recording; without it, the per-turn closure variance is a one-dimensional search of refits, too slow to repeat 80 times
UNSIMULATED = {"placement_error", "placement_var"}
RIVAL_WINDOW_IC = 20.0  # a significant rival this close may still win Cox's test against the leader
RIVALS_MAX = 3  # rivals put to Cox's test per step, closest first (each test simulates up to 80 recordings)


def select_effects(prob: Problem, state: ModelState, cands: list[Candidate], specs, base_priors, alpha: float, pen: float,
            worlds: Worlds | None = None):
    """Forward selection. Returns ([(Step, ModelState)] in the order accepted, ambiguities).

    The best significant effect (lowest information criterion) is taken only when no other catalogued
    effect the recording can test explains the mismatch about as well (within ``AMBIGUOUS_IC``), unless
    Cox's test (rivals.py) rejects that rival's world while keeping the effect's own. A significant rival
    further behind (within ``RIVAL_WINDOW_IC``) is taken instead when the test rejects the leader's world
    and keeps the rival's. What stays unresolved is reported as an ambiguity.
    """
    steps: list[tuple[Step, ModelState]] = []
    ambiguities: list[dict] = []
    remaining = list(cands)
    others = [s for s in specs if s.key not in {c.key for c in cands}]
    keys = {s_.name: s_.key for s_ in specs}
    cur = state
    cur_ic = criterion(cur, pen)
    cur_cv = press(cur.fit, prob)
    while remaining:
        trials = []
        for c in remaining:
            st = try_fit(prob, cur, c.key, base_priors)
            if st is None:
                continue
            lr = float(cur.fit.deviance[0] - st.fit.deviance[0])
            # on top of an accepted effect, the drop is judged against the misfit that is left (quasi-likelihood
            # F-test): a model that still leaves residuals beyond noise does not get to add effects to soak them up
            dispersion = max(1.0, float(st.fit.deviance[0]) / max(float(st.fit.dof[0]), 1.0))
            p = c.p_value if not steps else _conditional_p(lr / dispersion, c)
            if p < alpha:
                trials.append((c, st, lr, p))
        if not trials:
            break
        scored = sorted(((criterion(st, pen), c, st, lr, p) for c, st, lr, p in trials), key=lambda x: x[0])
        ic, c, st, lr, p = scored[0]
        cv = press(st.fit, prob)
        if not (ic < cur_ic and cv < cur_cv):
            break
        accepted = {x.name for x, _ in steps}
        # every rival explanation: name -> (criterion, key, fitted state, significant candidate or None, p)
        rivals: dict[str, tuple] = {}
        for r_ic, rc, rst, _, rp in scored[1:]:
            if rc.name != c.name and rc.name not in rivals:
                rivals[rc.name] = (r_ic, rc.key, rst, rc, rp)
        for o in others:
            if o.name == c.name or o.name in rivals or o.name in accepted:
                continue
            ost = try_fit(prob, cur, o.key, base_priors)
            if ost is not None:
                rivals[o.name] = (criterion(ost, pen), o.key, ost, None, 1.0)
        # a rival that explains different residuals is a second effect, not an alternative: with both
        # modelled the criterion improves again
        close = sorted((v[0], n) for n, v in rivals.items() if v[0] < ic + AMBIGUOUS_IC and n not in accepted
                       and not _complementary(prob, st, keys.get(n), base_priors, ic, pen))
        far = sorted((v[0], n) for n, v in rivals.items() if ic + AMBIGUOUS_IC <= v[0] < ic + RIVAL_WINDOW_IC
                     and v[3] is not None and n not in accepted)
        win, win_ic, win_cv = (c, st, p), ic, cv
        tests: list[dict] = []
        unresolved: list[str] = []
        for r_ic, n in close + far:
            near = r_ic < ic + AMBIGUOUS_IC
            if worlds is None or len(tests) >= RIVALS_MAX or UNSIMULATED & {win[0].key, rivals[n][1]}:
                if near:
                    unresolved.append(n)
                    break
                continue
            _, rkey, rst, rcand, rp = rivals[n]
            # a close rival that is itself significant may turn out the better explanation: its world being
            # plausible, the leader's is simulated too
            t = rival_test(worlds, cur, win[1], rst, win[0].key, rkey, win[0].name, n,
                           first="b" if near else "a", both=near and rcand is not None)
            w = t.winner()
            switch = False
            if w == n and rcand is not None:
                r_cv = press(rst.fit, prob)
                switch = r_ic < cur_ic and r_cv < cur_cv
            if switch:
                win, win_ic, win_cv = (rcand, rst, rp), r_ic, r_cv
                t = t.flipped()
            tests.append(t.to_dict())
            if not switch and w != win[0].name and near:
                unresolved.append(n)
                break
        (c, st, p), ic, cv = win, win_ic, win_cv
        unresolved = [n for n in unresolved if n != c.name]
        if unresolved:
            ambiguities.append({"candidates": [c.name] + unresolved,
                                "ic": {c.name: ic, **{n: rivals[n][0] for n in unresolved if n in rivals}},
                                "base": sorted(accepted), "rival_tests": tests})
            break
        steps.append((Step(c.name, c.key, cur.fit, st.fit, st.model, dict(st.variance), (cur_ic, ic), (cur_cv, cv), p,
                           c.statistic, tests), st))
        cur, cur_ic, cur_cv = st, ic, cv
        remaining = [r for r in remaining if r.name != c.name]
        others = [o for o in others if o.name != c.name]
    return steps, ambiguities


def _complementary(prob: Problem, st: ModelState, key: str | None, base_priors, ic: float, pen: float) -> bool:
    if key is None:
        return False
    both = try_fit(prob, st, key, base_priors)
    return both is not None and criterion(both, pen) < ic - AMBIGUOUS_IC


def _conditional_p(lr: float, c: Candidate) -> float:
    """p-value of a likelihood-ratio drop on top of an accepted effect.

    Score effects: chi-square with the tested dimension, scaled by the bootstrap's ratio of mean to
    dimension (the small-sample correction of the first test). Variance effects: chi-square with
    their number of variance parameters (conservative for a parameter on its boundary).
    """
    lr = max(lr, 0.0)
    if c.key == "bias_instability":
        return float(chi2_sf(lr, 2))
    if c.key == "placement_var":
        return float(chi2_sf(lr, 1))
    scale = max(1.0, c.null[0] * c.null[1] / max(c.dof, 1))
    return float(chi2_sf(lr / scale, max(c.dof, 1)))
