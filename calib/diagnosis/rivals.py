"""Telling two rival explanations apart: Cox's test of non-nested models by parametric bootstrap.

When two effects both explain a mismatch, the information criterion says which fits better, but not
whether a lead of that size is unusual. Each rival's fitted model is simulated (the recording's
motion replayed with that effect switched on, as ``null.with_effects`` does), every simulation is
fitted with both rivals exactly as the recording was, and the difference of their criteria
d = IC_a - IC_b is compared with the one the recording shows. A world whose simulations rarely give
a difference as far towards the other rival as observed is rejected: p_a = P(d* >= d_obs | a),
p_b = P(d* <= d_obs | b). An effect is named over its rival when its own world is plausible and
the rival's is not; otherwise the recording cannot tell them apart.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from calib.diagnosis.engine import Priors
from calib.diagnosis.extended_fits import ModelState, criterion, effective_params, fit_state, gm_of, refit_state, try_fit
from calib.diagnosis.gauss_newton import gauss_newton
from calib.diagnosis.null import Replay, replicate_problems, with_effects

RIVAL_BOOT = 40  # simulations of each rival's world
RIVAL_ALPHA = 0.025  # a world giving the observed difference less often than this is rejected (none of 40)


@dataclass
class Worlds:
    """What the simulations of a recording need: its replay under the base fit and how to refit a replicate."""

    replay: Replay
    base: ModelState  # the base model fitted to the recording (no effects)
    base_priors: Priors | None
    pen: float
    caps: np.ndarray | None
    a_design: np.ndarray | None
    seed: int
    tick: Callable[[str], None] | None = None  # told of each simulation fitted (what is being weighed), for progress


@dataclass
class RivalTest:
    """The outcome for rivals a and b: d = IC_a - IC_b, and how plausible each one's world finds it."""

    a: str
    b: str
    d_obs: float
    p_a: float | None  # None: that world was not simulated (the decision did not need it)
    p_b: float | None
    n_a: int = 0  # simulations of each world that were fitted (fewer when the outcome was clear early)
    n_b: int = 0
    hits_a: int = 0  # of those, how many gave a difference at least as far towards the other rival as observed
    hits_b: int = 0

    def winner(self) -> str | None:
        """The rival whose world is plausible while the other's is rejected, else None."""
        if self.p_a is None or self.p_b is None:
            return None
        if self.p_b < RIVAL_ALPHA <= self.p_a:
            return self.a
        if self.p_a < RIVAL_ALPHA <= self.p_b:
            return self.b
        return None

    def flipped(self) -> RivalTest:
        """The same test seen from b's side."""
        return RivalTest(self.b, self.a, -self.d_obs, self.p_b, self.p_a, self.n_b, self.n_a, self.hits_b, self.hits_a)

    def to_dict(self) -> dict:
        return {"rival": self.b, "criterion_difference": self.d_obs,
                "p_value_named": self.p_a, "simulations_named": self.n_a, "as_far_named": self.hits_a,
                "p_value_rival": self.p_b, "simulations_rival": self.n_b, "as_far_rival": self.hits_b}


def _replicate_difference(worlds: Worlds, prob, cur: ModelState, key_a: str, key_b: str) -> float:
    """IC_a - IC_b of one simulated recording, fitted as the recording was: the accepted effects, then each rival.

    The accepted model is refitted from the recording's own fit, its wander re-estimated; a placement error among
    them takes its heading prior from each recording's tilts, so that model is rebuilt effect by effect instead."""
    try:
        if "placement_error" in cur.keys:
            base = worlds.base
            fit = gauss_newton(prob, base.model, base.fit.psi, priors=worlds.base_priors, max_iter=10)
            st = ModelState(base.model, fit, worlds.base_priors, {}, ())
            for k in cur.keys:
                st = fit_state(prob, st, k, worlds.base_priors)
        else:
            st = refit_state(prob, cur)
    except (np.linalg.LinAlgError, ValueError, FloatingPointError):
        return np.nan
    sa = try_fit(prob, st, key_a, worlds.base_priors)
    sb = try_fit(prob, st, key_b, worlds.base_priors)
    if sa is None or sb is None:
        return np.nan
    return criterion(sa, worlds.pen) - criterion(sb, worlds.pen)


def debiased(world: ModelState, cur: ModelState, key: str) -> np.ndarray:
    """The world's parameters (P,) with the effect ``key`` shrunk to an unbiased size.

    A fitted effect is larger than the true one: its deviance drop is about the true effect's
    noncentrality plus its number of parameters p. Simulated at the fit, a world with many parameters
    would give its effect leads the recording cannot match; scaled by sqrt(1 - p / drop), the
    simulated effect has the size the recording supports."""
    psi = world.fit.psi[0].copy()
    sl = world.model.slices.get(key)
    if sl is None:
        return psi  # a variance effect: simulated at its fitted size
    drop = float(cur.fit.deviance[0] - world.fit.deviance[0])
    p = max(effective_params(world.fit) - effective_params(cur.fit), 0.0)
    psi[sl] *= np.sqrt(max(0.0, 1.0 - p / drop)) if drop > 0 else 0.0
    return psi


def world_p(worlds: Worlds, world: ModelState, psi: np.ndarray, cur: ModelState, key_a: str, key_b: str,
            d_obs: float, upper: bool, n: int, salt: int) -> tuple[float, int, int]:
    """How often n simulations of ``world`` (a fitted state of the recording, at parameters psi) give IC_a - IC_b at least as far as
    d_obs (above it when ``upper``): (p with the observation counted, simulations fitted, how many went as far).

    Simulation stops once the p-value can no longer fall under ``RIVAL_ALPHA``: the world is plausible."""
    replay = with_effects(worlds.replay, world.model, psi, gm_of(world), worlds.a_design)
    rng = np.random.default_rng([worlds.seed, salt])
    hits = used = 0
    for _ in range(n):
        prob = replicate_problems(replay, rng, 1, worlds.caps, worlds.a_design)
        d = _replicate_difference(worlds, prob, cur, key_a, key_b)
        if worlds.tick is not None:
            worlds.tick(f"weighing {key_a} against {key_b}")
        if not np.isfinite(d):
            continue
        used += 1
        hits += int(d >= d_obs) if upper else int(d <= d_obs)
        if (hits + 1) / (n + 1) >= RIVAL_ALPHA:
            break
    return (hits + 1) / (used + 1), used, hits


def rival_test(worlds: Worlds, cur: ModelState, st_a: ModelState, st_b: ModelState, key_a: str, key_b: str,
               name_a: str, name_b: str, first: str, n: int = RIVAL_BOOT, both: bool = False) -> RivalTest:
    """Cox's test of effect a against effect b, both fitted on top of ``cur``.

    ``first``: the world to simulate first ("a" or "b"); the other is simulated only if the first is
    rejected, since otherwise no winner can follow, or when ``both``: the first world being plausible
    then leaves the other's rejection to decide whether the first effect wins.
    """
    d_obs = criterion(st_a, worlds.pen) - criterion(st_b, worlds.pen)
    p: dict[str, float | None] = {"a": None, "b": None}
    used = {"a": 0, "b": 0}
    hits = {"a": 0, "b": 0}
    for side in (first, "b" if first == "a" else "a"):
        world, key, salt = (st_a, key_a, 1) if side == "a" else (st_b, key_b, 2)
        # in a's world a's lead is larger (d more negative): a is rejected when d_obs is unusually high
        p_side, used[side], hits[side] = world_p(worlds, world, debiased(world, cur, key), cur, key_a, key_b,
                                                 d_obs, side == "a", n, salt)
        p[side] = p_side
        if p_side >= RIVAL_ALPHA and not both:
            break
    return RivalTest(name_a, name_b, d_obs, p["a"], p["b"], used["a"], used["b"], hits["a"], hits["b"])
