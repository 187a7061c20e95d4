"""A whole kit in one protocol: accuracy, honesty and the loose-wearable check of ``calib.kit.estimator.calibrate_kit``.

Run: .venv/bin/python bench/kit.py [--sessions 200] [--kits 2,4,6] [--workers 2] [--json out.json]

For each kit size, ``--sessions`` simulated kits (``calib.simulator.kit.simulate_kit``: the paper's sensor errors, noise
0.03 deg/s, mounting rotations up to 2 deg, clocks within +-1 %, starts 0.5 s apart; seeds 0..sessions-1) are
calibrated together, and every wearable alone from the same motion (the closure estimator on its own recording).
Both learn the tray's heading spread from its turns, as by default (``--heading-prior-deg D`` states it instead: the
rows measured before the spread was learned stated 0.001 deg, the simulated tray being put back exactly).
Reported per parameter, pooled over
every wearable of every session: the 95th percentile of |error| for the kit and alone, that of the kit over 1.96 times
its rms bound and the 95th percentile of |error| / bound over 1.96 (each run against its own bound: the wearables'
bounds differ with their k, and one large one weighs on the rms), the gain (alone's p95 over the kit's), sd(error /
reported std), and the ceiling of the gain: what a wearable's k could be known to if the true motion were known
exactly (its own readings' noise against sum m^2 of its turn), over what its own turns' closure tells.

``--misalignment M``: every sensor's axes are not orthogonal (the off-diagonal entries of its K drawn in +-M); the
tables then add each wearable's tilt (K_xy / k_y, K_xz / k_z, K_yz / k_z) found by the kit against alone (whose turns
about its axes leave its tilt unseen unless its wobble identified it), and how often the kit chose a full K.

``--fault drop|clip|out``: the same kits, their first wearable (the reference unless the kit chooses another) either
losing 1.5 s of a drawn turn on its link (``drop``), or with a gyroscope range between the peaks of its two slowest
turns, so that two of its turns clip (``clip``), or lying on the table beside the tray (``out``, as the simulated tray
lays it: ``simulate_kit(..., out=0)``): the tables then give the other wearables' rows, and that wearable's apart
(``faulty``: how well the kit bridged it, against its stated uncertainty; of ``out``, how often the kit left it out, or
of two named it in its refusal). Without a fault, how often the kit left any wearable out is the false share.

Loose wearables: ``--sessions`` kits where one wearable (drawn) slips by 1-3 deg during a drawn turn (every other kit:
in the pause after the turn, the tray resting still): the share where exactly that wearable is flagged, and how far
from its slip the kit measured it turned (p95; a slip in a turn only at the rests, which the service does not say),
each apart; and the share of the kits above (nothing slipped) where any wearable is flagged.

``--guided K``: instead, K guided kit sessions of ``--kits``' first size through the real service (`gyrocal serve --mock N
--mock-kit --mock-speed 8`, with ``--misalignment`` its ``--mock-kit-misalignment``): the clinician's time per
wearable, the device time from the start to the kit's result over N, how many wearables passed, and how far each k
that passed is from the simulated truth against its stated uncertainty. The tray is
turned by its scripted clinician (5 s rests), or with ``--hand STYLE`` by a clinician who follows the kit's prompts
(mock_device.hand's styles: careful, hurried, ...), reading them as the kit page does. A kit in which a wearable did
not pass is printed on stderr with every wearable's reason; ``--service-log FILE`` keeps the service's log.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

import numpy as np

from calib.errors import GyrocalError
from calib.kit.estimator import calibrate_kit
from calib.pipeline import calibrate_protocol
from calib.simulator.kit import Slip, simulate_kit

HEADING_PRIOR_DEG: float | None = None  # the tray's heading spread stated to every calibration (None: learned)
NAMES = ("k_x", "k_y", "k_z", "b_x", "b_y", "b_z", "t_xy", "t_xz", "t_yz")  # t: the tilt (K_xy / k_y, ...)


def _tilt(K: np.ndarray) -> np.ndarray:
    """(K_xy / k_y, K_xz / k_z, K_yz / k_z): the share of one axis' true rate that reaches another's reading."""
    return (K / np.diag(K)[None, :])[[0, 0, 1], [1, 2, 2]]


def _with_fault(recs: list, truth, seed: int, fault: str | None) -> list:
    """``recs`` with the first wearable's fault (``--fault``): a 1.5 s link drop in a drawn turn, or a range that clips
    its two faster turns (``out``, beside the tray, is simulated so: ``simulate_kit``)."""
    if fault in (None, "out"):
        return recs
    r, dev = recs[0], truth.devices[0]
    if fault == "drop":
        turn = [s for s in truth.tray.stages if s.kind == "turn"][int(np.random.default_rng([seed, 11]).integers(3))]
        # on the wearable's own clock, which counts from its own power-up
        mid = dev.clock_origin_s + (0.5 * (turn.start_s + turn.end_s) - dev.start_s) * (1 + dev.clock_error)
        first = r.select(np.abs(r.t - mid) > 0.75)
    else:
        full_scale = float(np.sort(np.abs(r.gyro).max(axis=0))[:2].mean())
        first = replace(r, gyro=np.clip(r.gyro, -full_scale, full_scale), meta=replace(r.meta, gyro_full_scale_dps=full_scale))
    return [first, *recs[1:]]


def _session(args: tuple[int, int, float, str | None]) -> dict:
    n, seed, misalignment, fault = args
    recs, truth = simulate_kit(seed, n, misalignment=misalignment, out=0 if fault == "out" else None)
    recs = _with_fault(recs, truth, seed, fault)
    t0 = time.perf_counter()
    try:
        kit = calibrate_kit(recs, heading_prior_deg=HEADING_PRIOR_DEG)
    except GyrocalError as exc:
        return {"failed": str(exc), "named": getattr(exc, "wearable", None), "first": recs[0].meta.device_id}
    elapsed = time.perf_counter() - t0
    rows = []
    for i, (member, dev, rec) in enumerate(zip(kit.members, truth.devices, recs, strict=True)):
        r = member.result
        try:
            alone_v = _alone(rec)
        except GyrocalError:  # a turn it lost or clipped: alone, it would be turned again
            alone_v = np.full(9, np.nan)
        truth_v = np.concatenate([np.diag(dev.K_own), dev.b_own, _tilt(dev.K_own)])
        kit_v = np.concatenate([r.k, r.b, _tilt(r.matrix)]) if r is not None else np.full(9, np.nan)
        tilt_std = r.K_std[[0, 0, 1], [1, 2, 2]] / r.k[[1, 2, 2]] if r is not None and r.K_std is not None else [np.nan] * 3
        rows.append({
            "kit_err": (kit_v - truth_v).tolist(),
            "kit_std": np.concatenate([r.k_std, r.b_std, tilt_std]).tolist() if r is not None else [np.nan] * 9,
            "kit_bound": np.concatenate([r.k_bound, r.b_bound, [np.nan] * 3]).tolist() if r is not None else [np.nan] * 9,
            "alone_err": (alone_v - truth_v).tolist(),
            "ceiling": _ceiling(rec, truth, dev).tolist(),
            "faulty": bool(fault) and i == 0,
        })
    return {"rows": rows, "departed": kit.departed, "seconds": elapsed, "protocol_s": float(truth.tray.t[-1]),
            "axes": (kit.axes or {}).get("model"), "not_turned": kit.not_turned, "first": recs[0].meta.device_id}


def _alone(rec) -> np.ndarray:
    alone = calibrate_protocol(rec, method="closure", heading_prior_deg=HEADING_PRIOR_DEG)[0]
    return np.concatenate([alone.k, alone.b, _tilt(alone.matrix)])


def _ceiling(rec, truth, dev) -> np.ndarray:
    """Per axis: sqrt(n sum m^2 / (sum m)^2) over the turn about it, the most knowing the true motion could gain on k."""
    out = np.full(3, np.nan)
    for st in truth.tray.stages:
        if st.kind == "turn" and st.axis in ("x", "y", "z"):
            a = "xyz".index(st.axis)
            m = truth.tray.rate[st.start:st.end, a]
            out[a] = np.sqrt(m.size * np.sum(m**2) / np.sum(m) ** 2)
    return out


def _loose(args: tuple[int, int, float]) -> dict:
    n, seed, misalignment = args
    rng = np.random.default_rng([seed, 7])
    device, angle, turn = int(rng.integers(n)), float(rng.uniform(1.0, 3.0)), int(rng.integers(3))
    in_pause = bool(seed % 2) and turn < 2  # every other kit: in the pause after the turn (the last has a final rest)
    recs, _ = simulate_kit(seed, n, slip=Slip(device, angle, turn, in_pause=in_pause), misalignment=misalignment)
    try:
        kit = calibrate_kit(recs, heading_prior_deg=HEADING_PRIOR_DEG)
    except GyrocalError as exc:
        return {"failed": str(exc)}
    names = [m.name for m in kit.members]
    d = kit.members[device].coherence.departure if kit.members[device].coherence is not None else None
    # how far it turned, as the kit measures it: across its burst while the tray rested; of a slip in a turn, only its
    # attitude at the rests (which the service does not say: its own k absorbs part of such a slip)
    measured = float("nan") if d is None else d.step_deg if in_pause else d.angle_deg
    return {"found": kit.departed == [names[device]], "departed": kit.departed, "angle": angle, "in_pause": in_pause,
            "turned_error": measured - angle}


def _table(n: int, sessions: list[dict], faulty: bool | None = None) -> dict:
    """The pooled figures of every wearable's rows (``faulty``: only the faulty wearables', or only the others')."""
    ok = [s for s in sessions if "rows" in s]
    rows = [r for s in ok for r in s["rows"] if faulty is None or r["faulty"] == faulty]
    kit_err = np.abs(np.array([r["kit_err"] for r in rows]))
    alone_err = np.abs(np.array([r["alone_err"] for r in rows]))
    kit_std = np.array([r["kit_std"] for r in rows])
    bound = np.array([r["kit_bound"] for r in rows])
    z = np.array([r["kit_err"] for r in rows]) / kit_std
    with warnings.catch_warnings():  # the tilt has no bound, and orthogonal kits no tilt std: NaN columns
        warnings.simplefilter("ignore", RuntimeWarning)
        p95_kit, p95_alone = np.nanpercentile(kit_err, 95, axis=0), np.nanpercentile(alone_err, 95, axis=0)
        return {
            "kit": n, "sessions": len(sessions), "failed": len(sessions) - len(ok),
            "p95_kit": p95_kit.tolist(), "p95_alone": p95_alone.tolist(),
            "p95_over_bound": (p95_kit / (1.96 * np.sqrt(np.nanmean(bound**2, axis=0)))).tolist(),
            "p95_err_over_bound": (np.nanpercentile(kit_err / bound, 95, axis=0) / 1.96).tolist(),
            "gain": (p95_alone / p95_kit).tolist(), "sd_z": np.nanstd(z, axis=0).tolist(),
            "ceiling_k": np.nanmedian(np.array([r["ceiling"] for r in rows]), axis=0).tolist(),
            "false_flags": float(np.mean([bool(s["departed"]) for s in ok])),
            "left_out": float(np.mean([bool(s["not_turned"]) for s in ok])),
            # the first wearable named as the one that did not turn: left out of the kit, or named in its refusal
            "first_named": float(np.mean([s.get("not_turned") == [s["first"]] or s.get("named") == s["first"]
                                          for s in sessions])),
            "full_k": float(np.mean([s["axes"] == "upper-triangular" for s in ok])),
            "seconds_median": float(np.median([s["seconds"] for s in ok])),
            "protocol_s_per_wearable": float(np.median([s["protocol_s"] for s in ok]) / n),
        }


def _guided(n: int, sessions: int, hand: str | None = None, speed: float = 8.0, misalignment: float = 0.0,
            service_log: str | None = None) -> dict:
    """``sessions`` guided kit sessions of ``n`` simulated wearables through `gyrocal serve --mock-kit` (``hand``: the
    prompt-following clinician's style; None: the scripted one; ``misalignment``: the tray's sensors' axes;
    ``service_log``: a file the service's log is appended to). A kit in which some wearable did not pass is printed
    with each wearable's reason, on stderr."""
    import os
    import signal
    import subprocess
    import sys

    import httpx
    from local_service import free_port, scratch_dir, wait_until_up

    port = free_port()
    tmp = scratch_dir("gyrocal-kit-guided-")
    env = {**os.environ, "GYROCAL_API_TOKEN": "bench"}
    proc = subprocess.Popen([sys.executable, "-m", "calib.cli.main", "serve", "--port", str(port), "--db",
                             f"sqlite:///{tmp / 'store.sqlite3'}", "--mock", str(n), "--mock-kit", "--mock-speed", str(speed),
                             *(["--mock-scenario", f"hand:{hand}"] if hand else []),
                             *(["--mock-kit-misalignment", str(misalignment)] if misalignment else []), "--log-level", "warning"],
                            env=env, stdout=open(service_log or os.devnull, "a"), stderr=subprocess.STDOUT)
    c = httpx.Client(base_url=f"http://127.0.0.1:{port}", headers={"Authorization": "Bearer bench"}, timeout=60)
    per_device, passed, z_k = [], [], []
    try:
        wait_until_up(c)
        for _ in range(sessions):
            t0 = time.monotonic()
            kit_id = c.post("/kits/calibrate", json={"devices": [f"mock-{i + 1}" for i in range(n)]}).json()["session_id"]
            computed = None
            while True:
                snap = c.get(f"/sessions/{kit_id}").json()
                if computed is None and snap["state"] in ("computing", "done", "failed"):
                    computed = time.monotonic() - t0
                if snap["state"] in ("done", "failed", "cancelled"):
                    break
                time.sleep(0.1)
            per_device.append(computed * speed / n)
            passed.append(sum(bool(d["passed"]) for d in snap["devices"]))
            for d in snap["devices"]:  # a pass is honest when its k is within its stated uncertainty of the truth
                if d["passed"]:
                    truth = np.array(c.get(f"/devices/{d['device_id']}").json()["simulated_truth"]["k"])
                    z_k.extend(np.abs(np.array(d["result"]["k"]) - truth) / np.array(d["result"]["uncertainty"]["k"]))
            if passed[-1] < n:
                print(f"kit {kit_id}: " + "; ".join(f"{d['device_id']} {d['state']}: {d.get('reason') or 'passed'}"
                                                    for d in snap["devices"]), file=sys.stderr, flush=True)
            time.sleep(1.0)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=20)
    return {"kit": n, "sessions": sessions, "hand": hand or "scripted", "misalignment": misalignment,
            "seconds_per_wearable_median": float(np.median(per_device)), "passed_median": float(np.median(passed)),
            "all_passed": float(np.mean([p == n for p in passed])),
            "passed_k_error_over_std_max": float(np.max(z_k)) if z_k else None,
            "passed_k_within_3_std": float(np.mean(np.array(z_k) <= 3.0)) if z_k else None}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sessions", type=int, default=200)
    ap.add_argument("--kits", default="2,4,6")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--guided", type=int, default=0, metavar="K")
    ap.add_argument("--hand", default=None, metavar="STYLE", help="with --guided: the prompt-following tray clinician")
    ap.add_argument("--service-log", default=None, metavar="FILE", help="with --guided: append the service's log to FILE")
    ap.add_argument("--misalignment", type=float, default=0.0, metavar="M",
                    help="each sensor's axes are not orthogonal: the off-diagonal entries of its K drawn in +-M")
    ap.add_argument("--fault", choices=["drop", "clip", "out"], default=None,
                    help="the first wearable lost 1.5 s of a turn on its link, clips two of its turns, or lies beside the tray")
    ap.add_argument("--json", default=None)
    ap.add_argument("--heading-prior-deg", type=float, default=None, metavar="D",
                    help="state the tray's heading spread (default: learned from the turns)")
    args = ap.parse_args()
    sizes = [int(v) for v in args.kits.split(",")]
    global HEADING_PRIOR_DEG
    HEADING_PRIOR_DEG = args.heading_prior_deg  # before the workers are forked: each sees it
    if args.guided:
        out = _guided(sizes[0], args.guided, args.hand, misalignment=args.misalignment, service_log=args.service_log)
        print(f"guided kits of {out['kit']} ({out['hand']} clinician): clinician time {out['seconds_per_wearable_median']:.1f} s "
              f"per wearable (median of {out['sessions']}); {out['passed_median']:.0f} of {out['kit']} passed (median), all "
              f"passed in {100 * out['all_passed']:.0f} %; each k that passed within 3 of its std of the truth: "
              f"{100 * (out['passed_k_within_3_std'] or 0):.1f} % (the largest |error| / std "
              f"{out['passed_k_error_over_std_max'] or 0:.1f})")
        return
    out = {"accuracy": [], "loose": []}
    with ProcessPoolExecutor(args.workers) as pool:
        for n in sizes:
            sessions = list(pool.map(_session, [(n, s, args.misalignment, args.fault) for s in range(args.sessions)],
                                     chunksize=4))
            table = _table(n, sessions, faulty=False if args.fault else None)  # the faulty wearable's rows apart
            if args.fault:
                table["faulty"] = _table(n, sessions, faulty=True)
            loose = list(pool.map(_loose, [(n, s, args.misalignment) for s in range(args.sessions)], chunksize=4))
            found = [s["found"] for s in loose if "found" in s]
            table_loose = {"kit": n, "sessions": len(loose), "flagged_right": float(np.mean(found)),
                           "failed": len(loose) - len(found)}
            for where, in_pause in (("turn", False), ("pause", True)):  # in a turn, or while the tray rested
                some = [s for s in loose if "found" in s and s["in_pause"] == in_pause]
                said = np.abs([s["turned_error"] for s in some if s["found"]])
                table_loose[where] = {"sessions": len(some), "flagged_right": float(np.mean([s["found"] for s in some])),
                                      "turned_error_p95": float(np.percentile(said, 95)) if said.size else None}
            out["accuracy"].append(table)
            out["loose"].append(table_loose)
            print(f"kit of {n}: {table['sessions']} sessions ({table['failed']} failed), "
                  f"{table['seconds_median']:.2f} s per kit, protocol {table['protocol_s_per_wearable']:.1f} s per wearable")
            print("  param   p95 kit    p95 alone  gain   kit/(1.96 rms bound)  p95(err/bound)/1.96  sd(err/std)")
            calibrated = table["failed"] < table["sessions"]  # (of two, one beside the tray: every kit is refused)
            for j, name in enumerate((NAMES if args.misalignment else NAMES[:6]) if calibrated else []):
                print(f"  {name:5} {table['p95_kit'][j]:10.2e} {table['p95_alone'][j]:10.2e} {table['gain'][j]:6.2f}"
                      f" {table['p95_over_bound'][j]:14.2f} {table['p95_err_over_bound'][j]:20.2f} {table['sd_z'][j]:14.2f}")
            if args.fault == "out":
                print(f"  the first wearable beside the tray: named as not turned with the kit in "
                      f"{100 * table['first_named']:.1f} % of kits (left out, the rest calibrated; of two, in the refusal)")
            elif args.fault:
                f = table["faulty"]
                print(f"  the first wearable ({args.fault}): p95(err/bound)/1.96 "
                      f"{np.round(f['p95_err_over_bound'][:6], 2).tolist()}, sd(err/std) {np.round(f['sd_z'][:6], 2).tolist()}, "
                      f"p95 |err| k {np.array(f['p95_kit'][:3]).round(5).tolist()} b {np.array(f['p95_kit'][3:6]).round(4).tolist()}")
            print(f"  ceiling of the k gain (median, x/y/z): {np.round(table['ceiling_k'], 2).tolist()}; "
                  f"full K chosen in {100 * table['full_k']:.0f} % of kits")
            if not args.fault:
                print(f"  every wearable in the tray: one left out as not turned with the kit in {100 * table['left_out']:.1f} %")
            print(f"  nothing slipped: flagged in {100 * table['false_flags']:.1f} %;"
                  f" one slipped 1-3 deg: that one flagged in {100 * table_loose['flagged_right']:.1f} %"
                  f" ({table_loose['failed']} failed)")
            for where in ("turn", "pause"):
                w = table_loose[where]
                how = ("how far it turned measured within" if where == "pause"
                       else "its attitude at the rests (not said) off how far it turned by up to")
                print(f"    slipped in a {where}: {w['sessions']} kits, that one flagged in {100 * w['flagged_right']:.1f} %,"
                      f" {how} {w['turned_error_p95']:.2f} deg (p95)")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
