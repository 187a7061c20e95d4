"""`gyrocal history DEVICE`: a device's calibrations over time, each against the ones before it, with their
verifications and whether the device is due; `gyrocal verify FILE --id N`: a recording of one more full turn,
measured with a calibration and kept with it (plugged into calib's CLI; docs/lifecycle.md)."""

from __future__ import annotations

import argparse
import json
from datetime import datetime
from typing import TYPE_CHECKING, Any

from calib.apply.identity import SensorIdentity

from .cli import EXIT_OK, ServiceError, open_store, require_active_operator
from .config import DB_URL_HELP, DEFAULT_MAX_AGE_DAYS

if TYPE_CHECKING:
    from calib.judge.departure import Departure

    from .store import CalibrationRecord, StoredVerification


def register_history(sub: Any) -> None:
    """Add `gyrocal history`."""
    p = sub.add_parser(
        "history",
        help="a device's calibrations over time: values, uncertainties, sensor, departures from its history, verifications, due",
        description="List every accepted calibration of DEVICE, oldest first, with its k and b (± their standard deviations), "
        "its sensor and power-up, whether it departed from the calibrations before it (calib.judge.departure: a dropped or "
        "damaged sensor) and its latest verification turn; then whether the device is due for calibration.",
    )
    p.add_argument("device", help="the device's id")
    p.add_argument("--db", default=None, metavar="URL", help=DB_URL_HELP)
    p.add_argument("--max-age-days", type=float, default=DEFAULT_MAX_AGE_DAYS, metavar="DAYS",
                   help=f"a calibration older than this makes the device due (default {DEFAULT_MAX_AGE_DAYS:g})")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=cmd_history)


def _row(cal: CalibrationRecord, departed: list[Departure], verified: StoredVerification | None) -> dict[str, Any]:
    """A calibration as `gyrocal history --json` lists it."""
    unc = cal.uncertainty.model_dump() if cal.uncertainty is not None else {}
    ident = cal.identity or SensorIdentity()
    return {"id": cal.id, "accepted_at": cal.accepted_at.isoformat(timespec="seconds"), "source": cal.source, "operator": cal.operator,
            "k": cal.k, "k_std": unc.get("k"), "b": cal.b, "b_std": unc.get("b"), "serial": ident.serial,
            "boot_count": ident.boot_count, "temperature_c": ident.temperature_c,
            "departures": [d.to_dict() for d in departed],
            "verification": None if verified is None else verified.model_dump(mode="json")}


def cmd_history(args: argparse.Namespace) -> int:
    from calib.judge.departure import departures

    from .lifecycle import calibration_due

    store = open_store(args.db)
    cals = list(reversed(store.calibrations(args.device)))  # oldest first
    device = store.device(args.device)
    if not cals and device is None:
        raise ServiceError(f"no device {args.device!r} in {store.display_url}; `gyrocal serve` lists the devices it knows")
    verifications = store.verifications(args.device)
    rows = []
    for i, cal in enumerate(cals):
        before = [c.model_dump() for c in cals[:i]]
        latest = next((v for v in verifications if v.calibration_id == cal.id), None)
        rows.append(_row(cal, departures(cal.model_dump(), before), latest))
    current = cals[-1] if cals else None
    due = calibration_due(None if current is None else current.accepted_at, args.max_age_days,
                          calibration_identity=None if current is None else current.identity,
                          device_power_up=None if device is None else device["power_up"],
                          latest_watch=next(iter(store.watches(args.device, current.id, 1)), None) if current else None)
    if args.json:
        print(json.dumps({"device_id": args.device, "calibrations": rows, "calibration_due": due.model_dump()}, indent=2))
        return EXIT_OK
    print(f"{args.device}: {len(rows)} calibration(s), oldest first")
    for r in rows:
        k = "  ".join(f"{v:.5f}" for v in r["k"])
        b = "  ".join(f"{v:+.3f}" for v in r["b"])
        who = f"#{r['id']} {r['accepted_at']} {r['source']} by {r['operator']}"
        sensor = " ".join(x for x in (f"serial {r['serial']}" if r["serial"] else "", f"power-up #{r['boot_count']}"
                                      if r["boot_count"] is not None else "",
                                      f"{r['temperature_c']:.1f} degC" if r["temperature_c"] is not None else "") if x)
        print(f"  {who}\n    k {k}   b {b} deg/s" + (f"\n    {sensor}" if sensor else ""))
        for d in r["departures"]:
            print(f"    DEPARTS: {d['text']}")
        v = r["verification"]
        if v:
            print(f"    verified {v['at'][:19]}: {v['calibrated_deg']:.2f} ± {v['uncertainty_deg']:.2f} deg calibrated, "
                  f"{v['raw_deg']:.2f} raw ({'confirmed' if v['confirmed'] else 'NOT confirmed'})")
    print(f"due: {'yes' if due.due else 'no'} ({due.reason})")
    return EXIT_OK


def register_verify(sub: Any) -> None:
    """Add `gyrocal verify`."""
    from calib.cli.options import add_reading_arguments

    p = sub.add_parser(
        "verify",
        help="measure a recorded verification turn with a calibration (360 deg ± its uncertainty) and keep it with it",
        description="Find the full turn between two rests in FILE, measure its angle raw and with calibration #ID (or the "
        "current calibration of --device), print it, and keep the verification with the calibration in the store.",
    )
    add_reading_arguments(p)
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--id", type=int, default=None, metavar="N", help="the calibration's id")
    which.add_argument("--device", default=None, metavar="ID", help="the device whose current calibration is verified")
    p.add_argument("--operator", required=True, metavar="NAME", help="who verifies (an operator of the store)")
    p.add_argument("--db", default=None, metavar="URL", help=DB_URL_HELP)
    p.set_defaults(func=cmd_verify)


def cmd_verify(args: argparse.Namespace) -> int:
    from calib import __version__
    from calib.apply.correction import Correction
    from calib.cli.options import read_recording_args
    from calib.judge.verification import NoVerificationTurn, verify_turn

    from .workers.compute import recording_csv

    store = open_store(args.db)
    cal = store.calibration(args.id) if args.id is not None else store.current_calibration(args.device)
    if cal is None:
        raise ServiceError(f"no calibration {'#' + str(args.id) if args.id is not None else 'of ' + repr(args.device)} in "
                           f"{store.display_url}; `gyrocal history DEVICE` lists them")
    require_active_operator(store, args.operator)
    rec = read_recording_args(args).recording
    try:
        found = verify_turn(rec, Correction.from_json(cal.model_dump(mode="json")),
                            None if cal.uncertainty is None else cal.uncertainty.model_dump())
    except NoVerificationTurn as exc:
        raise ServiceError(f"{args.file}: {exc}") from None
    kept = store.add_verification(cal.id, args.operator, __version__, found, source="upload",
                                  recording_csv=recording_csv(rec), n_samples=len(rec))
    verdict = "confirmed: the calibration holds" if found.confirmed else "NOT confirmed: calibrate again, or check the turn"
    at = "" if kept.at is None else ", " + datetime.fromisoformat(kept.at).isoformat(timespec="seconds")
    print(f"calibration #{cal.id}: the turn about {found.dominant_axis} measured {found.calibrated_deg:.2f} ± "
          f"{found.uncertainty_deg:.2f} deg calibrated, {found.raw_deg:.2f} raw; {verdict} (kept as {kept.session_id}{at})")
    return EXIT_OK

