"""How long a calibration of a real recording takes, beside the tool the recording came with.

gyrocal: `calib.pipeline.calibrate_protocol` on imucal's Ferraris session (it finds the rests and turns itself, and
fits the accelerometer too), in this process, best of --runs. imucal (not a dependency of gyrocal): its own
`FerrarisCalibration().compute` on the same file given its labelled sections, run by the Python given with
--imucal-python (one with imucal installed: `python3 -m venv v && v/bin/pip install imucal`), best of --runs.

Usage: .venv/bin/python bench/calibration_speed.py [--runs 30] [--imucal-python PATH]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

REAL = Path(os.environ.get("GYROCAL_REAL_DATA", Path(__file__).resolve().parents[2] / "shared" / "data" / "real"))
SESSION = REAL / "imucal" / "example_ferraris_session.csv"
SECTIONS = REAL / "imucal" / "example_ferraris_session_list.json"
FS = 102.4

IMUCAL = """
import json, sys, time
import pandas as pd
from imucal import FerrarisCalibration, ferraris_regions_from_section_list
data = pd.read_csv(sys.argv[1])
sections = pd.DataFrame(json.load(open(sys.argv[2]))).T
runs = int(sys.argv[3])
best = float("inf")
for _ in range(runs):
    t = time.perf_counter()
    regions = ferraris_regions_from_section_list(data, sections)
    cal = FerrarisCalibration().compute(regions, sampling_rate_hz=102.4, from_acc_unit="m/s^2", from_gyr_unit="deg/s")
    best = min(best, time.perf_counter() - t)
print(best)
"""


def gyrocal_best(runs: int) -> tuple[float, list[float]]:
    from calib.io.readers import read_recording
    from calib.pipeline import calibrate_protocol

    rec = read_recording(SESSION, fs=FS)
    calibrate_protocol(rec)  # imports and first-call costs out of the figure
    best, k = float("inf"), []
    for _ in range(runs):
        t = time.perf_counter()
        result, _used = calibrate_protocol(rec)
        best = min(best, time.perf_counter() - t)
        k = [float(v) for v in result.k]
    return best, k


def main() -> int:
    from calib.blas import single_threaded_blas

    single_threaded_blas()  # as the command line runs: one BLAS thread (calib.blas)
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=30)
    p.add_argument("--imucal-python", default=None, help="a Python with imucal installed, to time it beside gyrocal")
    args = p.parse_args()
    if not SESSION.exists():
        print(f"imucal's session not found at {SESSION}: set GYROCAL_REAL_DATA", file=sys.stderr)
        return 2
    best, k = gyrocal_best(args.runs)
    print(f"gyrocal, stages found and accelerometer fitted: {best * 1000:.1f} ms (best of {args.runs}); "
          f"k = {', '.join(f'{v:.5f}' for v in k)}")
    if args.imucal_python:
        out = subprocess.run([args.imucal_python, "-c", IMUCAL, str(SESSION), str(SECTIONS), str(args.runs)],
                             capture_output=True, text=True, timeout=600)
        if out.returncode:
            print(f"imucal could not be run: {out.stderr.strip().splitlines()[-1]}", file=sys.stderr)
            return 2
        theirs = float(out.stdout.strip())
        print(f"imucal, given the labelled sections: {theirs * 1000:.1f} ms (best of {args.runs}); "
              f"gyrocal / imucal = {best / theirs:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
