"""Is the calibration still true: `calib.watch` over simulated study days (`calib.simulator.study_day`).

Per setting, N days of --hours each, their calibration the truth's k and b at the calibration's temperature:
- quiet: no event, with a temperature column: how often any parameter is said to have moved (false alarms), and the
  bias temperature coefficient against the truth (within 20 %);
- k: a drop changes one axis's k by --k-step (0.5 %) at a random time: found on that axis, among the days whose
  re-orientations exercised it at least 4 times (and among all);
- b: a drop changes one axis's b by --b-step (0.1 deg/s): found;
- no-temp: no event, no temperature column: false alarms, and how often the warm-up is named as the wearer's warmth;
- apply: two days of one sensor: the temperature model the first day's watch measured (calib.apply.temperature)
  applied to the second day, against its calibration alone: the attitude drift each walking bout accumulates (the
  norm of the integrated rate error over the bout, deg), median over the bouts.
Also the watch's time per hour of recording at 100 Hz (the simulation's time apart). Days run in --jobs processes.

Usage: .venv/bin/python bench/watch_days.py [--days 500] [--hours 1] [--jobs 2] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np

from calib.apply.correction import Correction
from calib.simulator.study_day import StudyEvent, simulate_study_day
from calib.watch import watch

SETTINGS = ("quiet", "k", "b", "no-temp", "apply")


def two_days(seed: int, hours: float) -> dict[str, Any]:
    """A sensor's first day watched, its temperature model applied to its second: each walking bout's drift."""
    from calib.apply.temperature import model_from_watches
    from calib.simulator.simulate import SensorParams

    rng = np.random.default_rng([seed, 8])
    same = {"params": SensorParams.paper_random(rng), "bias_tc": rng.choice([-1.0, 1.0], 3) * rng.uniform(0.01, 0.05, 3),
            "scale_tc": rng.choice([-1.0, 1.0], 3) * rng.uniform(1e-4, 3e-4, 3)}
    first, day1 = simulate_study_day(seed, 3600.0 * hours, **same)
    second, day2 = simulate_study_day(seed + 500_000, 3600.0 * hours, temp_cal_c=day1.temp_cal_c, **same)
    cor = Correction(K=np.diag(day1.params.k), b=day1.params.b.copy())
    model = model_from_watches([watch(first, cor, temp_cal_c=day1.temp_cal_c).to_json()], day1.temp_cal_c)
    alone, _ = cor.apply(second.gyro, second.accel)
    assert model is not None and day2.rate is not None
    modelled = model.rates(cor, second.gyro, second.accel, second.temp)
    dt = second.intervals_s[:, None]
    bouts = []
    for start, end in day2.walks:
        inside = (second.t >= start) & (second.t < end)
        bouts.append([float(np.linalg.norm(((r[inside] - day2.rate[inside]) * dt[inside]).sum(axis=0))) for r in (alone, modelled)])
    return {"setting": "apply", "seed": seed, "bouts": bouts}


def one_day(setting: str, seed: int, hours: float, k_step: float, b_step: float) -> dict[str, Any]:
    if setting == "apply":
        return two_days(seed, hours)
    rng = np.random.default_rng([seed, 7])
    duration = 3600.0 * hours
    event = None
    if setting in ("k", "b"):
        size = (k_step if setting == "k" else b_step) * float(rng.choice([-1.0, 1.0]))
        event = StudyEvent(float(rng.uniform(0.4, 0.8) * duration), setting, int(rng.integers(3)), size)
    rec, day = simulate_study_day(seed, duration, event=event, temperature_channel=setting != "no-temp")
    t0 = time.perf_counter()
    report = watch(rec, Correction(K=np.diag(day.params.k), b=day.params.b.copy()), temp_cal_c=day.temp_cal_c)
    seconds = time.perf_counter() - t0
    verdicts = {p.name: p.verdict for p in report.parameters}
    out: dict[str, Any] = {"setting": setting, "seed": seed, "seconds_per_hour": seconds / hours, "verdicts": verdicts,
                           "exercised": report.scale.exercised}
    if event is not None:
        name = f"{event.kind}_{'xyz'[event.axis]}"
        out["target"] = name
        out["found"] = verdicts[name] == "moved"
        out["others_moved"] = [n for n, v in verdicts.items() if v == "moved" and n != name]
    else:
        out["others_moved"] = [n for n, v in verdicts.items() if v == "moved"]
    tc = report.bias.temperature_coeff
    if tc is not None:
        out["bias_tc_within_20pct"] = bool(np.all(np.abs(tc - day.bias_tc) <= 0.2 * np.abs(day.bias_tc)))
    out["warmth_named"] = report.bias.warmth_change is not None
    return out


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    by: dict[str, Any] = {}
    for setting in SETTINGS:
        rs = [r for r in rows if r["setting"] == setting]
        if not rs:
            continue
        if setting == "apply":
            bouts = np.array([b for r in rs for b in r["bouts"]])
            by[setting] = {"sensors": len(rs), "bouts": len(bouts), "drift_deg_median_calibration_alone": float(np.median(bouts[:, 0])),
                           "drift_deg_median_with_temperature_model": float(np.median(bouts[:, 1])),
                           "ratio_of_medians": float(np.median(bouts[:, 1]) / np.median(bouts[:, 0]))}
            continue
        s: dict[str, Any] = {"days": len(rs), "false_moved": float(np.mean([bool(r["others_moved"]) for r in rs])),
                             "seconds_per_hour_median": float(np.median([r["seconds_per_hour"] for r in rs]))}
        if setting in ("k", "b"):
            s["found"] = float(np.mean([r["found"] for r in rs]))
            if setting == "k":
                ok = [r for r in rs if r["exercised"]["xyz".index(r["target"][-1])] >= 4]
                s["found_exercised_4"] = float(np.mean([r["found"] for r in ok])) if ok else None
                s["days_exercised_4"] = len(ok)
        if setting == "quiet":
            s["bias_tc_within_20pct"] = float(np.mean([r.get("bias_tc_within_20pct", False) for r in rs]))
        if setting == "no-temp":
            s["warmth_named"] = float(np.mean([r["warmth_named"] for r in rs]))
        s["cannot_tell"] = {n: float(np.mean([r["verdicts"][n] == "cannot tell" for r in rs]))
                            for n in ("k_x", "k_y", "k_z", "b_x", "b_y", "b_z")}
        by[setting] = s
    return by


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--days", type=int, default=500, help="days per setting (default 500)")
    ap.add_argument("--hours", type=float, default=1.0, help="each day's length, compressed (default 1 h)")
    ap.add_argument("--k-step", type=float, default=0.005)
    ap.add_argument("--b-step", type=float, default=0.1)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--settings", default=",".join(SETTINGS))
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    settings = args.settings.split(",")
    with ProcessPoolExecutor(args.jobs) as pool:
        futures = [pool.submit(one_day, s, 1000 * (i + 1) + seed, args.hours, args.k_step, args.b_step)
                   for i, s in enumerate(settings) for seed in range(args.days)]
        rows = []
        for n, f in enumerate(futures, 1):
            rows.append(f.result())
            if n % 50 == 0:
                print(f"{n}/{len(futures)} days", file=sys.stderr, flush=True)
    result = summary(rows)
    if args.json:
        print(json.dumps(result, indent=2))
        return
    for setting, s in result.items():
        print(setting, json.dumps(s))


if __name__ == "__main__":
    main()
