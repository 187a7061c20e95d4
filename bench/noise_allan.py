"""Noise from a long rest: `calib.noise` on simulated hours whose Allan variance has a closed form
(`calib.simulator.rest_noise`).

Three noises, --runs hours of each at 100 Hz, three gyroscope axes each:
- white: white noise of density N = 0.01 (deg/s)/sqrt(Hz);
- random walk: the same white noise and a rate random walk K = 2e-4 (deg/s)/sqrt(s);
- Gauss-Markov: the same white noise and a Gauss-Markov bias of sigma 0.01 deg/s, correlation time 30 s.
For each: the noise density's relative error (median, p95, and within 5 %), and for each parameter the share of
axes where the curve showed it whose 95 % interval holds the truth (N and K the closed form's; B the first local
minimum of the closed-form deviation on the same octave grid, over sqrt(2 ln 2 / pi): the reading's own definition).
Then `gyrocal noise` on one hour with the accelerometer at 100 Hz, wall time (reading the CSV, the six axes, the plot).

Usage: .venv/bin/python bench/noise_allan.py [--runs 200] [--jobs 2] [--json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from calib.noise.analysis import noise
from calib.noise.terms import B_FACTOR
from calib.simulator.rest_noise import RestNoise, simulate_rest

NOISES = {"white": RestNoise(density=0.01), "random walk": RestNoise(density=0.01, random_walk=2e-4),
          "Gauss-Markov": RestNoise(density=0.01, gm_sigma=0.01, gm_tc_s=30.0)}
FS = 100.0


def first_floor(adev: np.ndarray) -> float | None:
    """The first local minimum of a deviation curve (None when it only falls)."""
    for i in range(1, adev.size - 1):
        if adev[i] < adev[i - 1] and adev[i] <= adev[i + 1]:
            return float(adev[i])
    return None


def one(kind: str, seed: int) -> dict[str, list[Any]]:
    """One simulated hour of ``kind``: per axis, (seen, covered) per parameter and N's relative error."""
    truth = NOISES[kind]
    report = noise(simulate_rest(seed, 3600.0, FS, truth))
    tau = report.gyro[0].curve.tau_s
    floor = first_floor(np.sqrt(truth.avar(tau)))
    out: dict[str, list[Any]] = {"N": [], "K": [], "B": [], "B_at_tau": [], "rel": []}
    for a in report.gyro:
        for key, r, true in (("N", a.density, truth.density), ("K", a.random_walk, truth.random_walk),
                             ("B", a.bias_instability, None if floor is None else floor / B_FACTOR)):
            if r.seen and true:
                out[key].append(bool(r.lo95 <= true <= r.hi95))
        b = a.bias_instability
        if b.seen and floor is not None:  # against the closed form at the averaging time the floor was read at
            at = float(np.sqrt(truth.avar(np.array([b.tau_s])))[0]) / B_FACTOR
            out["B_at_tau"].append(bool(b.lo95 <= at <= b.hi95))
        out["rel"].append(None if not a.density.seen else a.density.value / truth.density - 1)
    return out


def cli_time() -> dict[str, float]:
    """`gyrocal noise` on one hour with the accelerometer, wall time (three runs, the least)."""
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "rest.csv"
        from calib.io.readers import write_native_csv

        write_native_csv(simulate_rest(1, 3600.0, FS, NOISES["random walk"], RestNoise(density=1e-4, random_walk=2e-6)), path)
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            subprocess.run([str(Path(sys.executable).with_name("gyrocal")), "noise", str(path), "--json"], check=True,
                           capture_output=True)
            times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        noise(simulate_rest(1, 3600.0, FS, NOISES["random walk"], RestNoise(density=1e-4, random_walk=2e-6)))
        return {"cli_s": min(times), "numerics_and_simulation_s": time.perf_counter() - t0}


def _cover(row: dict[str, Any], key: str) -> str:
    return "—" if row[f"{key}_covered"] is None else f"{100 * row[f'{key}_covered']:.1f} % ({row[f'{key}_seen']})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows: dict[str, Any] = {}
    with ProcessPoolExecutor(args.jobs) as pool:
        for kind in NOISES:
            results = list(pool.map(one, [kind] * args.runs, range(args.runs)))
            merged = {k: [v for r in results for v in r[k]] for k in ("N", "K", "B", "B_at_tau", "rel")}
            rel = np.abs([v for v in merged["rel"] if v is not None])
            rows[kind] = {"density_rel_error_median": float(np.median(rel)), "density_rel_error_p95": float(np.percentile(rel, 95)),
                          "density_within_5pct": float(np.mean(rel <= 0.05)),
                          **{f"{k}_covered": None if not merged[k] else float(np.mean(merged[k])) for k in ("N", "K", "B", "B_at_tau")},
                          **{f"{k}_seen": len(merged[k]) for k in ("N", "K", "B", "B_at_tau")}, "axes": 3 * args.runs}
    rows["timing"] = cli_time()
    if args.json:
        print(json.dumps(rows))
        return
    print(f"{'noise':<14} {'N rel p95':>9} {'N ≤5 %':>7} {'N cover':>8} {'B cover (seen)':>15} {'B at its τ':>15} {'K cover (seen)':>15}")
    for kind in NOISES:
        r = rows[kind]
        print(f"{kind:<14} {100 * r['density_rel_error_p95']:8.2f}% {100 * r['density_within_5pct']:6.1f}% "
              f"{_cover(r, 'N'):>8} {_cover(r, 'B'):>15} {_cover(r, 'B_at_tau'):>15} {_cover(r, 'K'):>15}")
    print(f"gyrocal noise on 1 h at 100 Hz with the accelerometer: {rows['timing']['cli_s']:.2f} s wall")


if __name__ == "__main__":
    main()
