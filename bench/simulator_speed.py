"""Speed of the protocol simulator: one paper-protocol batch of 500 runs, and single recordings.

Run: .venv/bin/python bench/simulator_speed.py [--runs 500] [--repeat 7]
Reports the best and median of several repeats, wall clock and process CPU time.
"""

from __future__ import annotations

import argparse
import statistics
import time

from calib.simulator import simulate, simulate_batch


def _measure(fn, repeat: int) -> tuple[list[float], list[float]]:
    wall, cpu = [], []
    for i in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        fn(i)
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
    return wall, cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=500)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    simulate_batch(0, 10, 0.03)  # warm-up (imports, first-call costs)

    for noise in (0.03, 0.15):
        wall, cpu = _measure(lambda i, noise=noise: simulate_batch(i, args.runs, noise), args.repeat)
        print(
            f"simulate_batch({args.runs} runs, noise {noise}): wall best {min(wall) * 1e3:.0f} ms, "
            f"median {statistics.median(wall) * 1e3:.0f} ms; cpu best {min(cpu) * 1e3:.0f} ms"
        )
    wall, cpu = _measure(lambda i: simulate(i), args.repeat)
    print(f"simulate (one recording): wall best {min(wall) * 1e3:.1f} ms, median {statistics.median(wall) * 1e3:.1f} ms")


if __name__ == "__main__":
    main()
