"""Cost of live stage tracking: microseconds of CPU per sample fed to a StageTracker.

Run: .venv/bin/python bench/stages_speed.py [--repeat 5]
Feeds simulated protocol recordings in batches of 1 to 1000 samples at 104 and 562.5 Hz, and 20
trackers at 562.5 Hz round-robin (as the service does for 20 devices); reports the best of the repeats
and, for the 20 devices, the share of one CPU core needed to keep up in real time.
"""

from __future__ import annotations

import argparse
import time

from calib.simulator import simulate
from calib.stages.detector import StageTracker, detect_stages


def _feed(rec, batch: int) -> float:
    tracker = StageTracker(rec.fs)
    c0 = time.process_time()
    for i in range(0, len(rec), batch):
        tracker.feed(rec.t[i : i + batch], rec.gyro[i : i + batch], rec.seq[i : i + batch])
    tracker.finish()
    return time.process_time() - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    for fs in (104.0, 562.5):
        rec, _ = simulate(0, noise=0.03, fs=fs)
        c0 = time.process_time()
        detect_stages(rec)
        print(f"fs {fs:6.1f} Hz, {len(rec)} samples: detect_stages {1e6 * (time.process_time() - c0) / len(rec):.2f} us/sample")
        for batch in (1, 8, 32, 128, 1000):
            best = min(_feed(rec, batch) for _ in range(args.repeat))
            print(f"  feed batches of {batch:4d}: {1e6 * best / len(rec):6.2f} us/sample")
    # 20 devices at 562.5 Hz, each sending 28-sample packets (50 ms), fed round-robin.
    recs = [simulate(s, noise=0.03, fs=562.5)[0] for s in range(20)]
    n = min(len(r) for r in recs)
    trackers = [StageTracker(r.fs) for r in recs]
    c0 = time.process_time()
    for i in range(0, n, 28):
        for tr, r in zip(trackers, recs, strict=False):
            tr.feed(r.t[i : i + 28], r.gyro[i : i + 28], r.seq[i : i + 28])
    cpu = time.process_time() - c0
    real_time = n / 562.5
    print(f"20 devices x {n} samples at 562.5 Hz: {1e6 * cpu / (20 * n):.2f} us/sample, "
          f"{100 * cpu / real_time:.1f}% of one core in real time")


if __name__ == "__main__":
    main()
