"""Speed of the closure estimator on single recordings: milliseconds per calibration, in-process.

Run: .venv/bin/python bench/closure_speed.py [--recordings 20] [--repeat 5] [--noise 0.03]

Simulates paper-protocol recordings at 104 Hz with a 10 s final rest (about 30 s in all), then times
for each, best of the
repeats, (a) calibrate_closure with the stages given, (b) calibrate_closure detecting the stages
itself, (c) the stage detection alone and (d) the extended model with stages given; reports the
median and the maximum over the recordings in wall-clock milliseconds.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from calib.estimators.closure.estimator import calibrate_closure
from calib.simulator import paper_protocol_script, simulate
from calib.stages.detector import detect_stages


def _best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recordings", type=int, default=20)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--noise", type=float, default=0.03)
    parser.add_argument("--seed", type=int, default=2024)
    args = parser.parse_args()

    rows = {"stages given": [], "stages detected": [], "detection alone": [], "extended, stages given": []}
    durations = []
    for i in range(args.recordings):
        proto = paper_protocol_script(np.random.default_rng(args.seed + i), final_still_s=10.0)
        rec, _ = simulate(args.seed + i, noise=args.noise, script=proto)
        durations.append(rec.duration_s)
        stages = detect_stages(rec)
        calibrate_closure(rec, stages)  # warm-up
        rows["stages given"].append(_best(lambda rec=rec, stages=stages: calibrate_closure(rec, stages), args.repeat))
        rows["stages detected"].append(_best(lambda rec=rec: calibrate_closure(rec), args.repeat))
        rows["detection alone"].append(_best(lambda rec=rec: detect_stages(rec), args.repeat))
        # the paper protocol's hand wobble identifies the off-diagonal terms only weakly; time it anyway
        try:
            rows["extended, stages given"].append(
                _best(lambda rec=rec, stages=stages: calibrate_closure(rec, stages, extended=True), args.repeat)
            )
        except Exception:  # noqa: BLE001 - a recording that does not identify them is skipped
            pass
    print(
        f"closure estimator, {args.recordings} simulated recordings ({np.mean(durations):.1f} s on average, 104 Hz, "
        f"noise {args.noise} deg/s), best of {args.repeat}:"
    )
    for name, t in rows.items():
        if t:
            t = np.array(t) * 1e3
            print(f"  {name:<24} median {np.median(t):6.1f} ms   max {t.max():6.1f} ms   ({len(t)} recordings)")


if __name__ == "__main__":
    main()
