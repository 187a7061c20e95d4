"""Guided sessions with a simulated clinician who follows the prompts: how often they pass, how long they take,
and how soon the page says "hold it still" after a turn stops.

Run: .venv/bin/python bench/guided_sessions.py [--sessions 200] [--hands careful,hurried,sloppy,bumps,gauge,old_gauge]

Every session runs the service's real state machine (server.live.session.GuidedSession, its stage detector and
turn checks) and the closure estimator in this process, fed 20 ms batches of a simulated wearable
(mock_device.prompted.PromptedSource, 104 Hz, the paper's sensor errors: k ~ U(0.8, 1.2), b ~ U(-5, 5) deg/s)
whose hand (mock_device.hand) reads every snapshot the session publishes, exactly as the page receives them.
Half the sessions of each hand are on a device that has an accepted calibration from an earlier power-up (its
k off the present one by 0.5 % rms), so the gauge shows true degrees with a 360 deg target; the other half have
none, so the gauge has no target. Seeds 0..N-1; three tries per turn (the service's default).

Columns: pass on the first try (every turn accepted the first time it was asked for), pass (after any retries,
without a restart), median and 95th-percentile protocol time (first sample to the last turn's pause done), the
largest scale-factor error of the passed calibrations (median over sessions), and the time from the hand's
motion stopping to the "hold it still" snapshot (median, 95th percentile).
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
from dataclasses import dataclass

import numpy as np

from calib.simulator import Still
from mock_device.hand import HANDS
from mock_device.prompted import PromptedSource
from server.config import Settings
from server.live.runner import compute_result
from server.live.session import GuidedSession
from server.live.snapshot_schema import SessionOut
from server.live.turn_watch import LiveAngle

FS = 104.0
BATCH_S = 0.02
FULL_SCALE_DPS = 500.0
LIMIT_S = 240.0
PRIOR_DRIFT = 0.005  # power-up to power-up change of k, rms fraction
RETRY_CODES = {"wrong_axis", "too_fast", "turn_incomplete", "turn_too_far", "turn_too_long", "sample_loss", "moved_during_pause",
               "out_of_tolerance"}


@dataclass(frozen=True)
class Outcome:
    hand: str
    seed: int
    calibrated_gauge: bool
    passed: bool
    first_try: bool
    state: str
    reason: str | None
    protocol_s: float | None
    k_error: float | None
    stop_to_hold_s: tuple[float, ...]


def run_session(hand: str, seed: int, calibrated_gauge: bool, late_page_s: float = 0.0) -> Outcome:
    """One guided session of ``hand`` on a fresh simulated device (seed). With ``late_page_s`` each snapshot reaches
    the hand up to that much device time late (uniformly at random, in order: a starved page), taken as seen when it arrives,
    as the hand's eyes over the network take it (``PromptedSource.observe_now``)."""
    src = PromptedSource(seed=seed, hand=hand)
    src.prepare(FS)
    k_true = np.asarray(src.params.k)
    live_angle = LiveAngle()
    if calibrated_gauge:
        drift = 1.0 + PRIOR_DRIFT * np.random.default_rng([seed, 0xD21F]).standard_normal(3)
        live_angle = LiveAngle.from_calibration(list(k_true * drift))
    now = [0.0]
    placing: list[float] = []
    computing_at: list[float] = []
    late = np.random.default_rng([seed, 0x1A7E])
    in_flight: list[tuple[float, dict]] = []  # (device time it reaches the hand, snapshot)

    def listen(kind: str, snapshot: SessionOut) -> None:
        snap = snapshot.model_dump(mode="json", exclude_unset=True)  # as the page receives it
        if late_page_s > 0:  # in order, as one event stream delivers them
            due = now[0] + float(late.uniform(0.0, late_page_s))
            in_flight.append((max(due, in_flight[-1][0]) if in_flight else due, snap))
        else:
            src.hand.observe(snap)
        if snap["phase"] == "placing" and kind in ("prompt", "state"):
            placing.append(float(snap["live"]["t_device_s"]))
        if snap["state"] == "computing" and kind == "state":  # the last time: a turn asked again comes before it
            computing_at[:] = [float(snap["live"]["t_device_s"])]

    session = GuidedSession("bench", "bench-device", Settings(db_url="sqlite://"), listener=listen, clock=lambda: now[0],
                            live_angle=live_angle)
    session.connected(FS, {"sensor_model": "simulated"}, FULL_SCALE_DPS)
    session.publish()
    n = int(round(BATCH_S * FS))
    i = 0
    k_error = None
    while not session.finished and i < LIMIT_S * FS:
        for arrived in [f for f in in_flight if f[0] <= now[0]]:
            in_flight.remove(arrived)
            src.observe_now(arrived[1])
        blk = src.block(i, i + n)
        t = np.arange(i, i + n) / FS
        now[0] = float(t[-1])
        session.feed(t, blk.gyro, blk.accel, np.arange(i, i + n))
        i += n
        if session.state == "computing":
            # as the service does: the result is judged, and may ask a turn again (the device streams on)
            result = compute_result(session)
            session.set_result(result)
            k_error = float(np.max(np.abs(np.asarray(result.k) / k_true - 1.0)))
    retried = any(w.code in RETRY_CODES for w in session.warnings)
    passed = session.state == "done" and bool(session.passed)
    return Outcome(hand, seed, calibrated_gauge, passed, passed and not retried, str(session.state), session.reason_code,
                   computing_at[0] if computing_at else None, k_error if passed else None, _stop_latencies(src, placing))


def _stop_latencies(src: PromptedSource, placing: list[float]) -> tuple[float, ...]:
    """For each "hold it still" snapshot, the time since the hand's motion before it ended."""
    ends = np.asarray(src.segment_bounds[1:], dtype=float) / FS  # each segment's end
    moving = np.array([not isinstance(s, Still) for s in src.segments])
    motion_ends = ends[: moving.size][moving]
    out = []
    for tp in placing:
        before = motion_ends[motion_ends <= tp + 0.3]
        if before.size:
            out.append(tp - float(before[-1]))
    return tuple(out)


def _one(args: tuple[str, int, bool, float]) -> Outcome:
    return run_session(*args)


def table(outcomes: list[Outcome], hands: list[str]) -> list[str]:
    head = (f"{'hand':<10} {'gauge':<10} {'sessions':>8} {'1st try':>8} {'pass':>7} {'median s':>9} {'p95 s':>6} "
            f"{'k err':>7} {'stop->hold med/p95 s':>21}  failures")
    lines = [head, "-" * len(head)]
    for hand in hands:
        for label, cal in (("target", True), ("no target", False), ("all", None)):
            rows = [o for o in outcomes if o.hand == hand and (cal is None or o.calibrated_gauge == cal)]
            if not rows:
                continue
            times = [o.protocol_s for o in rows if o.protocol_s is not None]
            kerr = [o.k_error for o in rows if o.k_error is not None]
            lat = [v for o in rows for v in o.stop_to_hold_s]
            fails: dict[str, int] = {}
            for o in rows:
                if not o.passed:
                    key = o.reason or o.state
                    fails[key] = fails.get(key, 0) + 1
            lines.append(
                f"{hand:<10} {label:<10} {len(rows):>8} {100 * np.mean([o.first_try for o in rows]):>7.1f}% "
                f"{100 * np.mean([o.passed for o in rows]):>6.1f}% {np.median(times) if times else float('nan'):>9.1f} "
                f"{np.percentile(times, 95) if times else float('nan'):>6.1f} "
                f"{100 * np.median(kerr) if kerr else float('nan'):>6.2f}% "
                f"{np.median(lat) if lat else float('nan'):>10.3f}/{np.percentile(lat, 95) if lat else float('nan'):.3f}  "
                + (", ".join(f"{k} {v}" for k, v in sorted(fails.items())) or "-")
            )
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=200, help="sessions per hand (half with a calibrated gauge)")
    ap.add_argument("--hands", default=",".join(HANDS), help=f"comma-separated, of {', '.join(HANDS)}")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--late-page", type=float, default=0.0, metavar="S",
                    help="each snapshot reaches the hand up to S s of device time late (a starved page)")
    args = ap.parse_args()
    hands = [h.strip() for h in args.hands.split(",") if h.strip()]
    unknown = [h for h in hands if h not in HANDS]
    if unknown:
        print(f"unknown hand(s) {', '.join(unknown)}: choose from {', '.join(HANDS)}", file=sys.stderr)
        return 2
    work = [(h, seed, seed % 2 == 0, args.late_page) for h in hands for seed in range(args.sessions)]
    outcomes: list[Outcome] = []
    with multiprocessing.Pool(args.jobs) as pool:
        for k, o in enumerate(pool.imap_unordered(_one, work, chunksize=4), start=1):
            outcomes.append(o)
            print(f"\r{k}/{len(work)} sessions", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    print("\n".join(table(outcomes, hands)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
