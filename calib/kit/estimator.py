"""Calibrate a kit: every wearable of one tray from the tray's one rest and three full turns.

1. Clocks: each wearable's stamps are mapped onto the reference's (``calib.kit.clocks``, refined in the coupling).
2. Coupling: each wearable's readings are fitted as A m_ref + c over every sample (``calib.kit.coupling``).
3. The kit's mean: every wearable's readings, mapped into the reference's, averaged with weights 1 / noise^2. Its
   stages are the kit's (a rest is when all rest), and the closure estimator calibrates it with the noise of N
   wearables averaged: the full turns fix the common scale √N times better than any one wearable's.
4. Each wearable's K and b follow from the mean's through its coupling (``calib.kit.members``).
5. Departure: a wearable whose attitude came apart from the others' (``calib.kit.departure``) is left out and the kit
   solved again without it; it gets its calibration alone, marked departed. Of two wearables that came apart, the
   one whose own turns close worse departed.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from calib.errors import GyrocalError, KitRefusal
from calib.estimators.closure.estimator import calibrate_closure
from calib.estimators.closure.fit import KPrior
from calib.estimators.closure.heading import heading_report
from calib.estimators.closure.placement import HeadingSpread
from calib.judge.acceptance import misclosure
from calib.kit.axes import KitAxes, kit_axes
from calib.kit.clocks import IDENTITY, ClockMap
from calib.kit.coupling import IDENTITY_MAP, LinearMap, fit_map, reading_noise, resting, runs
from calib.kit.departure import BURST_DPS, DEPARTURE_DEG, NO_DEPARTURE, departures
from calib.kit.heading import MeanRefit, Tray, tray_heading
from calib.kit.members import PARAMETERS, MemberParams, member_params, rest_bias
from calib.kit.result import Coherence, KitMember, KitResult
from calib.kit.together import follows, odd_one_out, refusal_of_two
from calib.kit.turn_rows import member_turn_rows
from calib.kit.turns import gaps, lost_in
from calib.numerics.attitude import cumulative_attitude
from calib.pipeline import calibrate_protocol, with_rate_uncertainty
from calib.recording import Recording
from calib.result import CalibrationResult
from calib.stages.detector import detect_stages
from calib.stages.plateaus import find_plateaus
from calib.stages.stage import Stage

METHOD = "kit-closure"
CONSENSUS_PASSES = 2
Progress = Callable[[float, str], None]


def calibrate_kit(recordings: Sequence[Recording], names: Sequence[str] | None = None, *, protocol: str = "auto",
                  heading_prior_deg: float | None = None, progress: Progress | None = None,
                  turns_kept: Sequence[Sequence[tuple[float, float]]] | None = None) -> KitResult:
    """Calibrate every wearable of a kit from one recording each of one motion of the tray.

    ``names``: one per recording (default: the recordings' device ids or sources). ``protocol``, ``heading_prior_deg``
    as for ``calib.pipeline.calibrate_protocol``. ``turns_kept``: per recording, the turns its live guidance took
    (start and end on its own stamps, s); a motion of the tray none of them took (a turn asked again: the try that
    fell short) is then no turn of the kit's. Raises GyrocalError when the recordings are not one kit's (fewer than
    two, names repeated, too little shared motion) or the kit's mean recording holds no protocol."""
    names = _names(recordings, names)
    say = progress or (lambda fraction, stage: None)
    clipped = [_clipped(r) for r in recordings]
    clock_runs = [runs(r)[~c] for r, c in zip(recordings, clipped, strict=True)]  # only a lost link starts a clock run
    recordings = [r.select(~c) if c.any() else r for r, c in zip(recordings, clipped, strict=True)]
    members = _most_complete_first(recordings)
    left_out: list[int] = []
    alone: dict[int, CalibrationResult | GyrocalError] = {}
    seen: dict[int, tuple[ClockMap, Coherence]] = {}  # a departed wearable's clock and departure, when it was found
    not_turned: list[int] = []  # wearables that did not turn with the others at all (calib.kit.together)
    while True:
        say(min(0.1 + 0.3 * len(left_out), 0.8), "aligning the clocks and fitting the coupling")
        try:
            solved = _solve(recordings, names, members, protocol, heading_prior_deg, clock_runs, turns_kept)
        except KitRefusal as refused:
            odd = odd_one_out(recordings, names, members, refused) if refused.code == "not_one_motion" else None
            if odd is None:
                raise (refusal_of_two(recordings, names, members, refused) if len(members) == 2 else refused) from None
            not_turned.append(odd)
            members.remove(odd)
            continue
        flagged = [members[j] for j, d in enumerate(solved.departures) if d.departed]
        if not flagged:
            break
        # how far each came apart, by either sign, in units of what makes a departure
        angle = {i: max(solved.departures[members.index(i)].angle_deg / DEPARTURE_DEG,
                        solved.departures[members.index(i)].burst_dps / BURST_DPS) for i in flagged}
        if len(members) == 2:  # two that came apart from each other: the one whose own turns close worse
            for i in flagged:
                alone.setdefault(i, _alone(recordings[i], protocol, heading_prior_deg))
            blamed = max(flagged, key=lambda i: (_worst_closure(alone[i]), angle[i]))
        else:  # the others carry a share of its slip in their comparison with the rest: it came apart the most
            blamed = max(flagged, key=lambda i: angle[i])
        j = members.index(blamed)
        seen[blamed] = (solved.clocks[blamed], Coherence(solved.maps[blamed].residual_sd, solved.maps[blamed].noise_sd,
                                                         solved.departures[j]))
        left_out.append(blamed)
        members.remove(blamed)
    say(0.9, "each wearable's calibration")
    refit = MeanRefit(solved.mean_rec, solved.mean, heading_prior_deg) if solved.mean.method == "closure" else None
    axes = kit_axes(solved.mean, [(solved.maps[i], solved.clocks[i]) for i in members], refit)
    # the spread from the fit the axes rest on (calib.kit.heading)
    tray = refit.tray if refit is not None and refit.tray is not None else tray_heading(solved.mean, heading_prior_deg)
    out = _members(recordings, names, solved, members, axes, tray)
    for i in left_out:
        alone.setdefault(i, _alone(recordings[i], protocol, heading_prior_deg))
        out[i] = _departed_member(names[i], alone[i], len(recordings), *seen[i])
    for i in not_turned:
        out[i] = KitMember(names[i], None, IDENTITY, float("nan"), None, turned=False,
                           error=f"{names[i]} did not turn with the kit: its readings do not follow the others' motion")
    warnings = [f"{names[i]}'s readings reached its gyroscope's full scale in {int(c.sum())} samples: the kit bridged "
                "them from the other wearables' readings of the same motion" for i, c in enumerate(clipped) if c.any()]
    warnings += [f"{names[i]} came apart from the kit: it moved in its slot, or its readings do not follow the tray's "
                 "motion; it was calibrated alone from its own turns; seat it firmly and calibrate it again"
                 for i in left_out]
    warnings += [f"{names[i]} did not turn with the kit (its readings do not follow the others' motion): it was left "
                 "out; check it was in the tray and switched on, and calibrate it again" for i in not_turned]
    say(1.0, "done")
    return KitResult(out, names[solved.ref], solved.mean, warnings, axes.to_dict())


class _Solved:
    """The kit solved with the wearables ``members`` (the first the reference): clocks, each wearable's map from the
    kit's mean, the mean's recording and calibration, the times ``span`` of the mean's samples, and each wearable's
    departure."""

    def __init__(self, members: list[int], clocks: dict[int, ClockMap], maps: dict[int, LinearMap], mean_rec: Recording,
                 mean: CalibrationResult, rates: np.ndarray, noise: np.ndarray, reading: dict[int, np.ndarray]) -> None:
        self.ref, self.members, self.clocks, self.maps, self.mean = members[0], members, clocks, maps, mean
        self.mean_rec, self.span = mean_rec, mean_rec.t
        self.reading_noise = reading  # each wearable's readings' noise std per axis, deg/s
        rests = [(s.start, s.end) for s in mean.stages if s.kind == "still"]
        self.departures = departures(rates, self.span, rests, noise) if len(members) >= 2 else [NO_DEPARTURE]


def _solve(recordings: Sequence[Recording], names: Sequence[str], members: list[int], protocol: str,
           heading_prior_deg: float | None,
           clock_runs: Sequence[np.ndarray], turns_kept: Sequence[Sequence[tuple[float, float]]] | None = None) -> _Solved:
    ref_i = members[0]
    ref = recordings[ref_i]
    noise = {i: reading_noise(recordings[i]) for i in members}
    ref_noise = noise[ref_i]
    clocks: dict[int, ClockMap] = {ref_i: IDENTITY}
    readings = {ref_i: ref.gyro}
    maps: dict[int, LinearMap] = {ref_i: IDENTITY_MAP}
    for i in members[1:]:
        coupling = follows(ref, recordings[i], (names[ref_i], names[i]), ref_noise, clock_runs[i])
        clocks[i], readings[i], maps[i] = coupling.clock, coupling.readings, coupling.map
    keep = np.ones(len(ref), dtype=bool)
    for values in readings.values():
        keep &= np.all(np.isfinite(values), axis=1)
    rows = np.nonzero(keep)[0]
    rows = np.arange(rows[0], rows[-1] + 1)
    y = {i: readings[i][rows] for i in members}
    if len(members) >= 2:
        rest = resting(ref)[rows]
        for _ in range(CONSENSUS_PASSES):  # each wearable against the mean of the others, not the reference alone
            mapped = {i: maps[i].invert(y[i]) for i in members}
            variance = {i: _mapped_variance(maps[i], noise[i]) for i in members}
            maps = {i: _against_others(i, members, y, mapped, variance, rest, noise[i]) for i in members}
    mapped = {i: maps[i].invert(y[i]) for i in members}
    variance = {i: _mapped_variance(maps[i], noise[i]) for i in members}
    mean_m = _weighted_mean([mapped[i] for i in members], [variance[i] for i in members])
    mean_rec = Recording(ref.t[rows], mean_m, None if ref.accel is None else ref.accel[rows],
                         None if ref.seq is None else ref.seq[rows],
                         meta=replace(ref.meta, source=f"the kit's {len(members)} wearables, in {names[ref_i]}'s frame",
                                      sample_rate_rel_std=None))  # each wearable's own rate's uncertainty is its own
    spans = None if turns_kept is None else [clocks[i].to_reference(np.asarray(span, dtype=float))
                                             for i in members for span in turns_kept[i]]
    stages = None if spans is None else _taken(detect_stages(mean_rec), spans)
    mean, _ = calibrate_protocol(mean_rec, protocol, "closure", stages=stages, heading_prior_deg=heading_prior_deg)
    if mean.quality.get("undetermined_axes") and len(members) >= 3:
        # one wearable's own motion (a slip in its slot in a short pause) moves the mean enough to join two turns into
        # one motion; the median of three or more wearables' readings does not move with one of them
        median = replace(mean_rec, gyro=np.nanmedian(np.array([mapped[i] for i in members]), axis=0))
        found = detect_stages(median)
        mean, _ = calibrate_protocol(mean_rec, protocol, "closure", stages=found if spans is None else _taken(found, spans),
                                     heading_prior_deg=heading_prior_deg)
    if mean.quality.get("undetermined_axes"):
        raise KitRefusal("the kit was not turned about every axis: " + "; ".join(mean.warnings[:1]), code="turn_missing")
    k_ref, b_ref = np.asarray(mean.k), np.asarray(mean.b)
    # calibrated, in the reference's frame; where a wearable lost samples, the kit's mean stands in (no departure)
    rates = np.array([np.where(np.isfinite(mapped[i]), mapped[i], mean_m) * k_ref + b_ref for i in members])
    rate_noise = np.array([np.sqrt(variance[i]) * k_ref for i in members])
    return _Solved(members, clocks, maps, mean_rec, mean, rates, rate_noise, noise)


def _taken(stages: list[Stage], spans: list[np.ndarray]) -> list[Stage]:
    """The kit mean's ``stages`` without the turns no wearable's live guidance took: a turn is taken when one of the
    wearables' taken turns (``spans``, reference time, s) covers half of it or of itself."""
    def taken(st: Stage) -> bool:
        return any(min(b, st.end_s) - max(a, st.start_s) >= 0.5 * min(b - a, st.end_s - st.start_s) for a, b in spans)

    return [st for st in stages if st.kind != "turn" or taken(st)]


def _against_others(i: int, members: list[int], y: dict[int, np.ndarray], mapped: dict[int, np.ndarray],
                    variance: dict[int, np.ndarray], rest: np.ndarray, own_noise: np.ndarray) -> LinearMap:
    others = [j for j in members if j != i]
    consensus = _weighted_mean([mapped[j] for j in others], [variance[j] for j in others])
    return fit_map(consensus, y[i], np.sqrt(1.0 / sum(1.0 / variance[j] for j in others)), rest, own_noise)


def _weighted_mean(signals: list[np.ndarray], variances: list[np.ndarray]) -> np.ndarray:
    """The inverse-variance weighted mean of signals (n, 3), each row over the signals that hold it (NaN: lost)."""
    stack = np.array(signals)
    weights = np.where(np.isfinite(stack), 1.0 / np.array(variances)[:, None, :], 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.nansum(stack * weights, axis=0) / weights.sum(axis=0)


def _mapped_variance(linear: LinearMap, noise: np.ndarray) -> np.ndarray:
    """The noise variance per axis of a wearable's readings mapped into the mean's space."""
    return (np.linalg.inv(linear.A) ** 2) @ (noise**2)


def _members(recordings: Sequence[Recording], names: list[str], solved: _Solved, members: list[int],
             axes: KitAxes, tray: Tray) -> list[KitMember]:
    mean = solved.mean
    out: list[KitMember] = [None] * len(recordings)  # type: ignore[list-item]
    for j, i in enumerate(members):
        rec, linear, clock = recordings[i], solved.maps[i], solved.clocks[i]
        params = member_params(axes.ref, linear, clock, axes.full)
        stages = _reaching_own_rests([_own_stage(s, solved.span, rec, clock) for s in mean.stages], rec)
        at_rest = np.concatenate([np.arange(s.start, s.end) for s in stages if s.kind == "still"])
        params = rest_bias(params, rec.gyro[at_rest].mean(axis=0), at_rest.size, solved.reading_noise[i])
        params = _own_turns_bias(rec, stages, params, tray)
        result = _result(rec, params, clock, solved, names, j, stages, solved.reading_noise[i], axes, tray)
        out[i] = KitMember(names[i], result, clock, params.mount_deg,
                           Coherence(linear.residual_sd, linear.noise_sd, solved.departures[j]))
    return out


def _own_turns_bias(rec: Recording, stages: list[Stage], params: MemberParams,
                    tray: Tray) -> MemberParams:
    """``params`` with b from the wearable's own rests and turns, its k known from the kit: the closure fit of its own
    recording, with the kit's k and its uncertainty as a prior. A turn's closure tells of b as well as the rests do
    where the wearable is put back where it was. Kept as they are (b from the rests) where a turn lost samples, where
    the fit cannot be made, and for a full K: b's error is then its tilt's through the rests' reading, which the rests'
    b carries, and the wobble of its own turns, which the kit's mean already weighed for the tilt, would count twice."""
    if params.tilt is not None or any(s.kind == "turn" and lost for s, lost in zip(stages, lost_in(stages, rec.t), strict=True)):
        return params
    std = np.full((3, 3), np.inf)
    std[np.diag_indices(3)] = params.k_std
    try:
        own = calibrate_closure(rec, stages=stages, heading_prior_deg=tray[0], k_prior=KPrior(params.K, std),
                                heading_source=tray[1])
    except GyrocalError:
        return params
    if own.b_std is None or own.b_bound is None or not np.all(np.isfinite(own.b)):
        return params
    return replace(params, b=np.asarray(own.b), b_std=np.asarray(own.b_std), b_bound=np.asarray(own.b_bound))


def _result(rec: Recording, params: MemberParams, clock: ClockMap, solved: _Solved, names: list[str], j: int,
            stages: list[Stage], noise: np.ndarray, axes: KitAxes, tray: Tray) -> CalibrationResult:
    """One wearable's calibration as an ordinary result: the mean's stages on its own samples, its own turns'
    closures with its own calibration, the mean's quality with the kit's block beside it and the tray's heading
    spread (``tray``)."""
    mean = solved.mean
    quality: Any = copy.deepcopy(mean.quality)
    if tray[1] == "kit" and tray[0] is not None and quality.get("placement"):  # carried by every wearable's fit
        quality["placement"]["heading"] = heading_report(HeadingSpread(tray[0], "kit"))
    quality["kit"] = {"devices": len(solved.members), "reference": names[solved.ref], "clock": clock.to_dict(),
                      "mount_deg": params.mount_deg, "consistency": solved.departures[j].to_dict(),
                      "axes": axes.to_dict()}
    if params.tilt is not None:
        quality["model"], quality["parameters"] = "upper-triangular", list(PARAMETERS)
        if mean.K is None:  # the kit, not the turns, told the wearables' axes apart
            quality["model_choice"] = {"asked": None, "reason": axes.reason}
    residuals = copy.deepcopy(mean.residuals)
    g = rec.gyro @ params.K.T + params.b
    attitude = cumulative_attitude(g, np.diff(rec.t, append=rec.t[-1] + np.median(np.diff(rec.t))))
    residuals["turns"] = member_turn_rows(residuals.get("turns") or [], stages, attitude, params.mount, rec.t)
    result = CalibrationResult(
        k=params.k, b=params.b, method=METHOD, stages=stages, quality=quality, k_std=params.k_std, b_std=params.b_std,
        k_bound=params.k_bound, b_bound=params.b_bound, noise_dps=noise, residuals=residuals,
        K=None if params.tilt is None else params.K, K_std=params.K_spread("std"),
        warnings=list(mean.warnings), iterations=mean.iterations, sample_rate_hz=rec.fs, n_samples=len(rec),
    )
    # its k is on its own stamps: a rate estimated from when its packets arrived carries its error into every k
    return with_rate_uncertainty(result, rec.meta.sample_rate_rel_std)


def _reaching_own_rests(stages: list[Stage], rec: Recording) -> list[Stage]:
    """The kit's first and last rests on a wearable's own samples, reaching on as far as it rested before and after
    the kit's span (its stream may start earlier or end later than the reference's), not over a motion there: a
    tray picked up again, or turned once more, before this wearable's stream stopped would put a turn in its rest
    reading, its b off by the turn's mean rate."""
    if not stages:
        return stages
    own = [s for s in detect_stages(rec) if s.kind == "still"]
    out = list(stages)
    first, last = out[0], out[-1]
    if first.kind == "still":
        start = min((s.start for s in own if s.start <= first.start < s.end), default=first.start)
        if start < first.start:
            out[0] = replace(first, start=start, start_s=float(rec.t[start]))
    if last.kind == "still":
        end = max((s.end for s in own if s.start <= last.end - 1 < s.end), default=last.end)
        if end > last.end:
            out[-1] = replace(last, end=end, end_s=float(rec.t[end - 1]))
    return out


def _own_stage(stage: Stage, span: np.ndarray, rec: Recording, clock: ClockMap) -> Stage:
    start_s, end_s = float(clock.to_own(span[stage.start])), float(clock.to_own(span[min(stage.end, span.size - 1)]))
    start, end = (int(v) for v in np.searchsorted(rec.t, [start_s, end_s]))
    return replace(stage, start=start, end=max(end, start + 1), start_s=start_s, end_s=end_s)


def _departed_member(name: str, alone: CalibrationResult | GyrocalError, n_devices: int, clock: ClockMap,
                     coherence: Coherence) -> KitMember:
    if isinstance(alone, GyrocalError):
        return KitMember(name, None, clock, float("nan"), coherence, departed=True, error=str(alone))
    alone.quality["kit"] = {"devices": n_devices, "reference": None, "clock": clock.to_dict(), "departed": True,
                            "consistency": coherence.departure.to_dict()}
    alone.warnings.insert(0, f"{name} came apart from the kit; this is its calibration from its own turns alone")
    return KitMember(name, alone, clock, float("nan"), coherence, departed=True)


def _alone(rec: Recording, protocol: str, heading_prior_deg: float | None) -> CalibrationResult | GyrocalError:
    try:
        return calibrate_protocol(rec, protocol, "closure", heading_prior_deg=heading_prior_deg)[0]
    except GyrocalError as exc:
        return exc


def _worst_closure(result: CalibrationResult | GyrocalError) -> float:
    if isinstance(result, GyrocalError):
        return float("inf")
    values = [misclosure(r) for r in result.residuals.get("turns") or []]
    return max((float(v) for v in values if v is not None), default=float("inf"))


def _clipped(rec: Recording) -> np.ndarray:
    """Which of a wearable's readings are clipped at its gyroscope's full scale (the stage detector's rule,
    ``calib.stages.plateaus``). The kit leaves them out as it does samples lost on the link: the other wearables
    read the same motion, so the turn is bridged, where a wearable alone would have to be turned again."""
    out = np.zeros(len(rec), dtype=bool)
    for p in find_plateaus(rec):
        out[p.start:p.end] = True
    return out


def _most_complete_first(recordings: Sequence[Recording]) -> list[int]:
    """The wearables' indices, the one that lost the fewest samples first (ties in the given order): the reference,
    on whose stamps the kit's mean is built. A reference with a gap in a turn would leave the mean's turn without
    samples every other wearable has."""
    missing = []
    for rec in recordings:
        step = np.diff(rec.t)
        lost = gaps(rec.t)
        missing.append(int(np.rint(step[lost] / np.median(step)).sum() - lost.sum()) if lost.any() else 0)
    return sorted(range(len(recordings)), key=lambda i: missing[i])


def _names(recordings: Sequence[Recording], names: Sequence[str] | None) -> list[str]:
    if len(recordings) < 2:
        raise GyrocalError("a kit needs at least two recordings, one per wearable, of one motion of the tray; to "
                           "calibrate one wearable use gyrocal calibrate")
    if names is None:
        names = [r.meta.device_id or r.meta.source or f"wearable {i + 1}" for i, r in enumerate(recordings)]
    names = [str(n) for n in names]
    if len(names) != len(recordings):
        raise GyrocalError(f"{len(names)} names for {len(recordings)} recordings: give one name per recording")
    if len(set(names)) != len(names):
        raise GyrocalError(f"the kit's wearables must have different names; got {', '.join(names)}")
    return names
