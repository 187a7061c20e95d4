"""Concurrent decisions on one session, many times over: how many accepts were tried, how many calibration rows
were stored, and whether the history still verifies.

Run: .venv/bin/python bench/store_races.py --db URL [--rounds 200] [--threads 8] [--processes 4]
Each round creates a finished session and releases ``threads`` threads (one barrier) that accept or discard
it at once (half each from the second half of the rounds on), then ``processes`` processes with their own
store connections do the same for another session. The store must keep exactly one decision per session,
one calibration row per accepted session, and intact hash chains.
"""

from __future__ import annotations

import argparse
import multiprocessing
import threading
import time
import uuid
from collections import Counter

from calib.result import CalibrationResult
from server.store import DecisionConflict, SessionEnd, Store

RESULT = CalibrationResult.from_dict({"k": [1.01, 0.99, 1.02], "b": [0.5, -0.25, 0.125], "method": "closure", "stages": []})


def _session(store: Store) -> str:
    sid = uuid.uuid4().hex
    store.create_session(sid, "bench-dev", "live", "connecting", "closure", "bench", "bench", {"sensor_model": "ICM-20948"})
    store.finish_session(sid, SessionEnd("done", result=RESULT, passed=True))
    return sid


def _decide(store: Store, sid: str, how: str) -> str:
    try:
        if how == "accept":
            store.accept(sid, "bench", RESULT)
        else:
            store.discard_session(sid, "bench")
        return how
    except DecisionConflict:
        return "conflict"


def _proc(url: str, sid: str, how: str, barrier: object, out: object) -> None:
    store = Store(url)
    barrier.wait()  # type: ignore[attr-defined]
    out.put(_decide(store, sid, how))  # type: ignore[attr-defined]
    store.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--db", required=True)
    ap.add_argument("--rounds", type=int, default=200)
    ap.add_argument("--threads", type=int, default=8)
    ap.add_argument("--processes", type=int, default=4)
    args = ap.parse_args()
    store = Store(args.db)
    ctx = multiprocessing.get_context("spawn")
    tried = Counter()
    winners: dict[str, str] = {}
    t0 = time.perf_counter()
    for r in range(args.rounds):
        mixed = r >= args.rounds // 2
        plan = [("discard" if mixed and i % 2 else "accept") for i in range(args.threads)]
        sid = _session(store)
        barrier, out = threading.Barrier(len(plan)), [""] * len(plan)

        def run(i: int, sid: str = sid, plan: list[str] = plan, barrier: threading.Barrier = barrier, out: list[str] = out) -> None:
            barrier.wait()
            out[i] = _decide(store, sid, plan[i])

        threads = [threading.Thread(target=run, args=(i,)) for i in range(len(plan))]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        tried.update(plan)
        wins = [o for o in out if o != "conflict"]
        assert len(wins) == 1, out
        winners[sid] = wins[0]
        if args.processes and r % 10 == 0:  # processes are slow to spawn: every tenth round
            sid = _session(store)
            pplan = [("discard" if mixed and i % 2 else "accept") for i in range(args.processes)]
            pb, q = ctx.Barrier(len(pplan)), ctx.Queue()
            procs = [ctx.Process(target=_proc, args=(args.db, sid, how, pb, q)) for how in pplan]
            for p in procs:
                p.start()
            pout = [q.get(timeout=120) for _ in procs]
            for p in procs:
                p.join()
            tried.update(pplan)
            pw = [o for o in pout if o != "conflict"]
            assert len(pw) == 1, pout
            winners[sid] = pw[0]
    elapsed = time.perf_counter() - t0
    accepted = sum(w == "accept" for w in winners.values())
    rows = store.calibrations("bench-dev")
    per_session = Counter(c.session_id for c in rows)
    report = store.verify()
    print(f"store: {store.dialect}; sessions raced: {len(winners)} ({elapsed:.1f} s)")
    print(f"accept requests tried: {tried['accept']}, discard requests tried: {tried['discard']}")
    print(f"sessions accepted: {accepted}, discarded: {len(winners) - accepted}")
    print(f"calibration rows stored: {len(rows)} (sessions with more than one: {sum(n > 1 for n in per_session.values())})")
    print(f"hash chains intact: {report.ok} ({report.rows})")


if __name__ == "__main__":
    main()
