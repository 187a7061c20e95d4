"""Peak memory of a model check against the recording's length, and how fast an oversized one is refused.

Run: .venv/bin/python bench/diagnosis_memory.py [--samples 10000,30000,60000,100000]
Each size is the paper protocol simulated at the rate that gives that many samples, diagnosed in a fresh
process (as the service's workers do); the peak resident memory of that process is reported. Then the
recording the service must refuse at once (20,000 rows whose last time stamp is 200,000 s) is timed.
The service's limits (100,000 samples, 3072 MB per worker) follow from these figures.
"""

from __future__ import annotations

import argparse
import multiprocessing
import resource
import time


def _one(n: int, out: object) -> None:
    from calib.diagnosis import diagnose
    from calib.simulator import simulate

    rec, _ = simulate(7, noise=0.03, fs=104.0)
    fs = 104.0 * n / len(rec)
    rec, _ = simulate(7, noise=0.03, fs=fs)
    t0 = time.perf_counter()
    diagnose(rec, max_samples=None)
    out.put((len(rec), fs, time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024))  # type: ignore[attr-defined]


def _refusal() -> tuple[float, float]:
    from calib.diagnosis import diagnose
    from calib.errors import RecordingTooLong
    from calib.io.readers import parse_recording_text

    rows = "".join(f"{i / 100:.2f},0.1,0.2,0.3\n" for i in range(20_000)) + "200000.0,0.1,0.2,0.3\n"
    t0 = time.perf_counter()
    rec = parse_recording_text("t,gx,gy,gz\n" + rows, None, "native", "span")
    try:
        diagnose(rec, max_samples=100_000)
    except RecordingTooLong:
        pass
    return time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", default="10000,30000,60000,100000")
    args = ap.parse_args()
    ctx = multiprocessing.get_context("spawn")
    print("samples  rate (Hz)  time (s)  peak memory (MB)  MB per 1000 samples")
    for n in (int(x) for x in args.samples.split(",")):
        q = ctx.Queue()
        p = ctx.Process(target=_one, args=(n, q))
        p.start()
        got, fs, secs, mb = q.get()
        p.join()
        print(f"{got:7d}  {fs:9.1f}  {secs:8.1f}  {mb:16.0f}  {mb / got * 1000:19.1f}")
    secs, mb = _refusal()
    print(f"refusing 20,000 rows spanning 200,000 s: {secs:.2f} s, peak memory {mb:.0f} MB (this process)")


if __name__ == "__main__":
    main()
