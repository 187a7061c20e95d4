"""The hand's heading spread learned from the turns that show it: accuracy and honesty of k and b with any hand.

Run: .venv/bin/python bench/heading.py [--runs 500] [--first-seed 0] [--workers 2] [--noises ...] [--tilts ...]
     [--headings ...] [--protocol paper|extended] [--json out.json]

Each setting simulates ``--runs`` paper-protocol recordings with the accelerometer (seeds ``--first-seed`` on) whose
hand puts the device back after each turn tilted by ``tilt`` and turned about the vertical by ``heading`` (deg, 1 sigma
per component, ``placement_error``), with white reading noise ``noise`` (deg/s), and calibrates each as ``gyrocal
calibrate`` does by default (stages detected, no heading prior stated). Reported per parameter: the 95th percentile of
|error|, sd(error / reported std), and how often the reported 95 % interval (``CalibrationResult.interval``: a
Student-t where the heading spread is learned from few turns) holds the truth, with that share's binomial standard
error (about 1 point for a 95 % interval over 500 runs: a row of 500 lands outside 93-97 % by chance alone in about 3 %
of settings); the share of fits whose chi-square p-value is below 0.001. Beside them, k_z's 95th percentile when the
calibration is told the true heading spread (``--heading-prior-deg``, 0 where there is none): the bound that knows it,
and how often its interval holds the truth.

On code that has no ``CalibrationResult.interval`` the interval is value ± 1.96 std (the figures before the change).
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from calib.effects.placement import PlacementError
from calib.pipeline import calibrate_protocol
from calib.simulator import extended_script_for_seed, simulate

NAMES = ("k_x", "k_y", "k_z", "b_x", "b_y", "b_z")
TILTS_DEG = (0.0, 0.3, 1.0, 2.0)
HEADINGS_DEG = (0.0, 0.1, 0.3, 1.0, 2.0)
NOISES_DPS = (0.03, 0.15)


@dataclass(frozen=True)
class Setting:
    tilt_deg: float
    heading_deg: float
    noise_dps: float
    protocol: str = "paper"


def _one(args: tuple[Setting, int]) -> np.ndarray:
    """(error, std, covered, p-value, k_z error told the true spread, [heading spread found (deg), k_z's degrees of
    freedom, k_z's interval told the true spread holds the truth]) of one run, (6, 6); NaN where refused."""
    setting, seed = args
    effects = [PlacementError(setting.tilt_deg, heading_std_deg=setting.heading_deg)] if (
        setting.tilt_deg or setting.heading_deg) else []
    script = extended_script_for_seed(seed) if setting.protocol == "extended" else None
    rec, truth = simulate(seed, noise=setting.noise_dps, effects=effects, script=script)
    out = np.full((6, 6), np.nan)
    try:
        res, _ = calibrate_protocol(rec)
        told, _ = calibrate_protocol(rec, heading_prior_deg=setting.heading_deg)
    except Exception:  # noqa: BLE001 - a refusal counts as a failed run
        return out
    value = np.concatenate((res.k, res.b))
    std = np.concatenate((res.k_std, res.b_std))
    truth_v = np.concatenate((truth.k, truth.b))
    if hasattr(res, "interval"):
        k_int, b_int = res.interval(0.95)
        lo, hi = np.concatenate((k_int[:, 0], b_int[:, 0])), np.concatenate((k_int[:, 1], b_int[:, 1]))
    else:
        lo, hi = value - 1.96 * std, value + 1.96 * std
    out[0], out[1] = value - truth_v, std
    out[2] = (lo <= truth_v) & (truth_v <= hi)
    out[3] = res.quality.get("p_value", np.nan)
    out[4] = np.concatenate((told.k - truth.k, told.b - truth.b))
    heading = res.quality.get("placement", {}).get("heading") or {}
    out[5, 0] = heading.get("spread_deg", np.nan)
    out[5, 1] = np.inf if res.k_dof is None else res.k_dof[2]
    told_interval = told.interval(0.95) if hasattr(told, "interval") else None
    if told_interval is not None:
        lo_z, hi_z = told_interval[0][2]
        out[5, 2] = float(lo_z <= truth.k[2] <= hi_z)
    return out


def measure(setting: Setting, runs: int, pool: ProcessPoolExecutor, first_seed: int = 0) -> dict:
    out = np.array(list(pool.map(_one, [(setting, s) for s in range(first_seed, first_seed + runs)], chunksize=8)))
    ok = np.all(np.isfinite(out[:, :3].reshape(runs, -1)), axis=1)
    err, std, covered, p_value, told = out[ok, 0], out[ok, 1], out[ok, 2], out[ok, 3, 0], out[ok, 4]
    found, dof, told_covered = out[ok, 5, 0], out[ok, 5, 1], out[ok, 5, 2]
    p95 = np.percentile(np.abs(err), 95, axis=0)
    p95_told = np.percentile(np.abs(told), 95, axis=0)
    share = covered.mean(axis=0)
    return {
        "protocol": setting.protocol, "tilt_deg": setting.tilt_deg, "heading_deg": setting.heading_deg,
        "noise_dps": setting.noise_dps,
        "runs": runs, "first_seed": first_seed, "refused": int((~ok).sum()),
        "p95": dict(zip(NAMES, p95.tolist(), strict=True)),
        "sd_z": dict(zip(NAMES, np.std(err / std, axis=0).tolist(), strict=True)),
        "coverage95": dict(zip(NAMES, share.tolist(), strict=True)),
        # the binomial standard error of those shares: a 95 % interval's share over 500 runs scatters by 1 point
        "coverage95_se": dict(zip(NAMES, np.sqrt(share * (1 - share) / ok.sum()).tolist(), strict=True)),
        "p_below_1e-3": float(np.mean(p_value < 1e-3)),
        "k_z_p95_told": float(p95_told[2]),
        "k_z_coverage95_told": float(np.nanmean(told_covered)),
        # k_z split by whether the REML found a heading spread: share, coverage, rms of error/std, median dof
        "k_z_by_spread": {name: _group(pick, covered[:, 2], err[:, 2] / std[:, 2], dof) for name, pick in
                          (("found_0", found == 0), ("found_above_0", found > 0))},
    }


def _group(pick: np.ndarray, covered: np.ndarray, z: np.ndarray, dof: np.ndarray) -> dict:
    if not pick.any():
        return {"share": 0.0}
    return {"share": float(pick.mean()), "coverage95": float(covered[pick].mean()),
            "z_rms": float(np.sqrt(np.mean(z[pick] ** 2))), "dof_median": float(np.median(dof[pick]))}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=500)
    p.add_argument("--first-seed", type=int, default=0, help="the first simulation seed (runs take the next ones)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--noises", type=float, nargs="*", default=list(NOISES_DPS))
    p.add_argument("--tilts", type=float, nargs="*", default=list(TILTS_DEG), help="tilt spreads (deg) to run")
    p.add_argument("--headings", type=float, nargs="*", default=list(HEADINGS_DEG), help="heading spreads (deg) to run")
    p.add_argument("--protocol", choices=("paper", "extended"), default="paper",
                   help="the protocol simulated (extended: four turns about each axis, both ways, slow and fast)")
    p.add_argument("--json", default=None, help="write the figures to this file")
    p.add_argument("--by-spread", action="store_true",
                   help="also print k_z's coverage split by whether a heading spread was found (share, coverage, z rms, dof)")
    args = p.parse_args()
    rows = []
    print(f"{'noise':>6} {'tilt':>5} {'head':>5} | {'k_x p95':>8} {'k_y p95':>8} {'k_z p95':>8} {'told':>8} | "
          f"{'sd k_x':>6} {'sd k_y':>6} {'sd k_z':>6} {'sd b max':>8} {'sd b min':>8} | {'cov k_z (se)':>13} {'cov told':>8} {'p<1e-3':>6}")
    with ProcessPoolExecutor(args.workers) as pool:
        for noise, tilt, heading in itertools.product(args.noises, args.tilts, args.headings):
            r = measure(Setting(tilt, heading, noise, args.protocol), args.runs, pool, args.first_seed)
            rows.append(r)
            p95, sd, cov = r["p95"], r["sd_z"], r["coverage95"]
            sd_b = [sd[n] for n in ("b_x", "b_y", "b_z")]
            print(f"{noise:6.2f} {tilt:5.1f} {heading:5.1f} | {p95['k_x']:8.1e} {p95['k_y']:8.1e} {p95['k_z']:8.1e} "
                  f"{r['k_z_p95_told']:8.1e} | {sd['k_x']:6.2f} {sd['k_y']:6.2f} {sd['k_z']:6.2f} {max(sd_b):8.2f} "
                  f"{min(sd_b):8.2f} | {cov['k_z']:6.3f} ({r['coverage95_se']['k_z']:.3f}) {r['k_z_coverage95_told']:8.3f} "
                  f"{r['p_below_1e-3']:6.3f}", flush=True)
            if args.by_spread:
                for name, g in r["k_z_by_spread"].items():
                    print(f"{'':>20} spread {name}: " + (f"{g['share']:.0%} of runs, k_z covered {g['coverage95']:.3f}, "
                          f"z rms {g['z_rms']:.2f}, median dof {g['dof_median']:.1f}" if g["share"] else "none"), flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
