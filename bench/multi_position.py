"""Calibration from re-orientations between rests (imu_tk's protocol), simulated: accuracy against each run's
Cramer-Rao bound, honesty of the reported uncertainty, the accelerometer's own calibration, and speed.

Run: .venv/bin/python bench/multi_position.py [--runs 200] [--noise 0.03 0.15] [--g-runs 50] [--motion-noise-runs 50]

The motion-noise section conceals a gyro noisier while it turns (the simulator's motion_noise effect, variance ratio
1.2-2.5, gyro noise 0.15 deg/s, accelerometer 1 mg so that the gyro's noise rules the re-orientations) and reports the
ratio measured, the re-orientations' chi-square against their noise with and without it counted, and err/std of k.

The g-sensitivity section conceals a random G (largest entry 0.02-0.15 (deg/s)/g, the simulator's drawn
range) in each run and reports how often the fit finds it, how much the fit improves, the parameters'
errors with and without it, and err/std of G; the accuracy runs above report how often G was fitted on a
sensor that has none (false positives; the test is at 0.1 %).

Each run simulates a 50 s rest, then 36 hand re-orientations of 90-180 deg (random axes, 1.5-3 s) between
5 s rests at 100 Hz, with gyro white noise sigma and accelerometer noise 5 mg; the accelerometer reads
through a random 9-parameter error (scale 0.97-1.03, offset +-50 mg, misalignment +-0.01 rad), which the
multi-position estimator fits together with the gyroscope (started from calib.estimators.accel's fit on the rests).
"bound" is the
|err| p95 an efficient unbiased estimator would reach: the p95 of |N(0, bound_i^2)| over the runs, bound_i
each run's own inverse-Fisher standard deviation (for the gyro: k and b; for the accelerometer: scale and
offset; the accelerometer's std is scaled by the fit's chi-square like the gyroscope's).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from calib.effects import MotionNoise  # noqa: E402
from calib.effects.axes import GSensitivity  # noqa: E402
from calib.estimators.multi_position.estimator import calibrate_multi_position  # noqa: E402
from calib.simulator import simulate  # noqa: E402
from calib.simulator.lab_scripts import multi_position_script as script  # noqa: E402
from calib.simulator.lab_scripts import with_accelerometer_error as with_accel_error  # noqa: E402

ACCEL_NOISE_G = 0.005


def p95_bound(bounds: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    z = rng.standard_normal((bounds.shape[0], 2000))
    return np.array([np.percentile(np.abs(bounds[:, j, None] * z).ravel(), 95) for j in range(bounds.shape[1])])


def run(noise: float, runs: int) -> None:
    errs, stds, bounds, a_errs, a_stds, times, g_fitted, floors, moving = [], [], [], [], [], [], 0, 0, 0
    for i in range(runs):
        rng = np.random.default_rng([7, i])
        rec, truth = simulate(10_000 + i, noise=noise, fs=100.0, script=script(rng), accel_noise_g=ACCEL_NOISE_G)
        rec, a_truth = with_accel_error(rec, rng)
        t0 = time.perf_counter()
        res = calibrate_multi_position(rec)
        times.append(time.perf_counter() - t0)
        g_fitted += bool(res.quality["g_sensitivity"]["fitted"])
        floors += sum(mg > 0 for mg in res.quality["accelerometer_floor"]["per_axis_mg"])
        moving += sum(c != 1.0 for c in res.quality["gyro_motion_noise"]["counted"])
        errs.append(np.concatenate([res.k - truth.k, res.b - truth.b]))
        stds.append(np.concatenate([res.k_std, res.b_std]))
        bounds.append(np.concatenate([res.k_bound, res.b_bound]))
        acc = res.quality["accelerometer"]  # fitted jointly with the gyroscope
        a_errs.append(np.concatenate([acc["scale"], acc["bias"]]) - a_truth)
        a_stds.append(np.concatenate([acc["uncertainty"]["scale"], acc["uncertainty"]["bias"]]))
        print(f"\r  noise {noise}: {i + 1}/{runs}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    errs, stds, bounds, a_errs, a_stds = map(np.array, (errs, stds, bounds, a_errs, a_stds))
    rng = np.random.default_rng(0)
    gb, ab = p95_bound(bounds, rng), p95_bound(a_stds, rng)
    names = ["k_x", "k_y", "k_z", "b_x", "b_y", "b_z"]
    print(f"\nnoise {noise} deg/s, accelerometer {1e3 * ACCEL_NOISE_G:g} mg, {runs} runs; median time {np.median(times):.3f} s; "
          f"g-sensitivity fitted (none simulated) in {g_fitted}; accelerometer floor found (white noise simulated) on "
          f"{floors} of {3 * runs} axes; gyro noise while moving counted on {moving} of {3 * runs} axes (none simulated)")
    print("  param   |err| p95     bound   ratio   err/std sd")
    for j, n in enumerate(names):
        e = np.percentile(np.abs(errs[:, j]), 95)
        print(f"  {n:6s}  {e:9.2e}  {gb[j]:9.2e}  {e / gb[j]:5.2f}   {np.std(errs[:, j] / stds[:, j]):.3f}")
    print("  accelerometer (scale s, offset o in g)")
    for j, n in enumerate(["s_x", "s_y", "s_z", "o_x", "o_y", "o_z"]):
        e = np.percentile(np.abs(a_errs[:, j]), 95)
        print(f"  {n:6s}  {e:9.2e}  {ab[j]:9.2e}  {e / ab[j]:5.2f}   {np.std(a_errs[:, j] / a_stds[:, j]):.3f}")


def concealed_g_sensitivity(runs: int, noise: float = 0.05) -> None:
    """Runs with a random g-sensitivity the recording does not announce: found, modelled, and the fit improved."""
    found, birge, rms, k_err, b_err, z = 0, [], [], [], [], []
    for i in range(runs):
        rng = np.random.default_rng([8, i])
        G = rng.uniform(-1.0, 1.0, (3, 3))
        G *= rng.uniform(0.02, 0.15) / np.abs(G).max()
        rec, truth = simulate(20_000 + i, noise=noise, fs=100.0, script=script(rng), accel_noise_g=ACCEL_NOISE_G,
                              effects=[GSensitivity(G)])
        res = calibrate_multi_position(rec)
        test = res.quality["g_sensitivity"]
        plain = calibrate_multi_position(rec, g_sensitivity=False)
        found += bool(test["fitted"])
        birge.append((test["without"]["birge_ratio"], res.quality["birge_ratio"]))
        rms.append((test["without"]["gravity_residual_rms_deg"], res.quality["gravity_residual_rms_deg"]))
        k_err.append((np.abs(plain.k - truth.k).max(), np.abs(res.k - truth.k).max()))
        b_err.append((np.abs(plain.b - truth.b).max(), np.abs(res.b - truth.b).max()))
        if res.G is not None and res.G_std is not None:
            z.append(((res.G - G) / res.G_std).ravel())
        print(f"\r  g-sensitivity: {i + 1}/{runs}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    med = lambda v: np.median(np.array(v), axis=0)  # noqa: E731
    p95 = lambda v: np.percentile(np.array(v), 95, axis=0)  # noqa: E731
    print(f"\nconcealed g-sensitivity (0.02-0.15 (deg/s)/g), noise {noise} deg/s, {runs} runs: found in {found}")
    print("                          without G    with G")
    print(f"  Birge ratio (median)    {med(birge)[0]:9.2f}  {med(birge)[1]:8.2f}")
    print(f"  gravity rms deg (median){med(rms)[0]:9.3f}  {med(rms)[1]:8.3f}")
    print(f"  max |dk| p95            {p95(k_err)[0]:9.2e}  {p95(k_err)[1]:8.2e}")
    print(f"  max |db| p95 deg/s      {p95(b_err)[0]:9.2e}  {p95(b_err)[1]:8.2e}")
    if z:
        print(f"  G err/std sd (all entries): {np.std(np.array(z)):.3f}")


def concealed_motion_noise(runs: int, noise: float = 0.15) -> None:
    """Runs with a gyro noisier while it turns, which the recording does not announce: measured, counted, and the
    re-orientations back at their noise."""
    rows = []
    for i in range(runs):
        rng = np.random.default_rng([9, i])
        ratio = rng.uniform(1.2, 2.5)
        rec, truth = simulate(30_000 + i, noise=noise, fs=100.0, script=script(rng), accel_noise_g=0.001,
                              effects=[MotionNoise(np.full(3, ratio))])
        res = calibrate_multi_position(rec)
        plain = calibrate_multi_position(rec, motion_noise=False)
        q, qp = res.quality, plain.quality
        rows.append([ratio, *q["gyro_motion_noise"]["variance_ratio"], qp["constraint_fit"]["motions"]["ratio"],
                     q["constraint_fit"]["motions"]["ratio"], *((plain.k - truth.k) / plain.k_std), *((res.k - truth.k) / res.k_std)])
        print(f"\r  motion noise: {i + 1}/{runs}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    a = np.array(rows)
    measured = a[:, 1:4] / a[:, :1]
    print(f"\nconcealed motion noise (variance ratio 1.2-2.5 while turning), gyro {noise} deg/s, accelerometer 1 mg, {runs} runs")
    lo, hi = np.percentile(measured, [5, 95])
    print(f"  measured / true ratio: median {np.median(measured):.2f}, 5-95 % {lo:.2f}-{hi:.2f}")
    print("                                   not counted   counted")
    print(f"  re-orientations chi2 / expected  {np.mean(a[:, 4]):11.2f}  {np.mean(a[:, 5]):8.2f}   (mean over runs)")
    print(f"  k err/std sd                     {np.std(a[:, 6:9]):11.2f}  {np.std(a[:, 9:12]):8.2f}")


def speed() -> None:
    """A 10-minute, 100 Hz multi-position recording: 50 s rest, 73 re-orientations between 5 s rests."""
    rng = np.random.default_rng(99)
    rec, _ = simulate(99, noise=0.05, fs=100.0, script=script(rng, n=73))
    calibrate_multi_position(rec)  # warm-up (imports, caches)
    t = []
    for _ in range(5):
        t0 = time.perf_counter()
        calibrate_multi_position(rec)
        t.append(time.perf_counter() - t0)
    print(f"\n10-minute recording ({rec.duration_s:.0f} s, {len(rec)} samples, 73 re-orientations): "
          f"{np.median(t):.3f} s median of 5 (accelerometer fit included)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--noise", type=float, nargs="+", default=[0.03, 0.15])
    ap.add_argument("--g-runs", type=int, default=50, help="runs with a concealed g-sensitivity")
    ap.add_argument("--motion-noise-runs", type=int, default=50, help="runs with a gyro noisier while it turns")
    args = ap.parse_args()
    for noise in args.noise:
        run(noise, args.runs)
    concealed_g_sensitivity(args.g_runs)
    concealed_motion_noise(args.motion_noise_runs)
    speed()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
