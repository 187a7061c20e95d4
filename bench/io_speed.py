"""Speed of reading and writing recordings: seconds per file for 100k-sample CSVs.

Run: .venv/bin/python bench/io_speed.py [--rows 100000] [--repeat 3]
Writes a native CSV with every optional column (full-precision floats) and an imucal-style CSV, reads
each back, and times a read that fails on a bad cell near the end (the slow, precise error path).
Reports the best of the repeats in wall-clock seconds.
"""

from __future__ import annotations

import argparse
import io
import time

import numpy as np

from calib.errors import RecordingError
from calib.io.readers import parse_recording_text, write_native_csv
from calib.recording import Recording


def _best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def _fails(text: str) -> None:
    try:
        parse_recording_text(text)
    except RecordingError:
        return
    raise AssertionError("the corrupted file was accepted")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    n = args.rows
    rng = np.random.default_rng(0)
    rec = Recording(
        t=np.arange(n) / 104.0, gyro=rng.normal(0, 50, (n, 3)), accel=rng.normal(0, 0.5, (n, 3)),
        seq=np.arange(n), temp=25 + rng.normal(0, 0.1, n),
    )
    buf = io.StringIO()
    print(f"write native, {n} rows: {_best(lambda: write_native_csv(rec, io.StringIO()), args.repeat):.3f} s")
    write_native_csv(rec, buf)
    native = buf.getvalue()
    print(f"read native ({len(native) / 1e6:.1f} MB): {_best(lambda: parse_recording_text(native), args.repeat):.3f} s")
    imucal = "n_samples,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n" + "".join(
        f"{i},{g[0]:.4f},{g[1]:.4f},{g[2]:.4f},{a[0]:.5f},{a[1]:.5f},{a[2]:.5f}\n"
        for i, g, a in zip(range(n), rec.gyro, rec.accel * 9.80665, strict=False)
    )
    print(f"read imucal ({len(imucal) / 1e6:.1f} MB): {_best(lambda: parse_recording_text(imucal, fs=104.0), args.repeat):.3f} s")
    lines = native.split("\n")
    lines[-10] = lines[-10].replace(",", ",x", 1)
    bad = "\n".join(lines)
    print(f"reject a bad cell on line {len(lines) - 9}: {_best(lambda: _fails(bad), args.repeat):.3f} s")


if __name__ == "__main__":
    main()
