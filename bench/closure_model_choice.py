"""How often the closure estimator chooses the extended (non-orthogonal) model by itself, with and without
non-orthogonal sensor axes, on simulated hand recordings of the paper protocol.

Run: .venv/bin/python bench/closure_model_choice.py [--runs 20] [--offdiag 0.02]

Each run simulates one paper-protocol recording (seed = run number, the simulator's hand wobble and tilt) and
calibrates it with calib.estimators.closure.estimator's default model choice; with ``--offdiag`` the sensor's K has that value in
each of K_xy, K_xz, K_yz (alternating signs). Reported: how many runs chose the extended model, and why the others
did not (``quality["model_choice"]["reason"]``, up to its first colon).
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter

from calib.effects.axes import AxisMisalignment
from calib.estimators.closure.estimator import calibrate_closure
from calib.simulator import simulate


def measure(runs: int, offdiag: float) -> list[str]:
    lines = []
    for value in (0.0, offdiag):
        effects = [AxisMisalignment((value, -value, value))] if value else []
        chosen, reasons = 0, Counter()
        for seed in range(runs):
            rec, _ = simulate(seed, effects=effects)
            res = calibrate_closure(rec)
            chosen += res.K is not None
            reasons[res.quality["model_choice"]["reason"].split(":")[0].split(" (")[0]] += 1
        why = "; ".join(f"{n}x {r}" for r, n in reasons.most_common())
        lines.append(f"off-diagonal {value:g}: extended chosen in {chosen} of {runs} ({why})")
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--offdiag", type=float, default=0.02)
    args = ap.parse_args()
    for line in measure(args.runs, args.offdiag):
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
