"""`gyrocal calibration DEVICE [--at TIME]`: the calibration in force for a device at a moment, from the store;
`gyrocal apply RECORDING (--device ID | --calibration FILE)`: a recording corrected by a calibration;
`gyrocal export`: a calibration for other tools; `gyrocal import FILE --device ID`: one made elsewhere into the
history (plugged into calib's CLI)."""

from __future__ import annotations

import argparse
import json
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from calib.apply.identity import DEFAULT_MAX_TEMPERATURE_CHANGE_C, SensorIdentity
from calib.errors import GyrocalError

from .cli import EXIT_OK, ServiceError, open_store, require_active_operator
from .config import DB_URL_HELP, DEFAULT_MAX_AGE_DAYS

if TYPE_CHECKING:
    from .config import CalibrationLimits

EXIT_NONE = 5  # no calibration had been accepted by then


def add_moment_arguments(p: argparse.ArgumentParser, at_help: str, db_help: str, max_age: bool = True) -> None:
    """--at, --db, the recording's identity and (with ``max_age``) the limits: which moment and recording, which store,
    what is too old or too far in temperature."""
    p.add_argument("--at", default=None, metavar="TIME", help=at_help)
    p.add_argument("--db", default=None, metavar="URL", help=db_help)
    _add_identity_arguments(p, "the recording's sensor and power-up (docs/lifecycle.md, 'Identity')", "during the recording",
                            boot_note=": a calibration of that power-up is taken first",
                            temperature_note=" (default: the recording's temp column, if any)")
    if max_age:
        p.add_argument("--max-age-days", type=float, default=DEFAULT_MAX_AGE_DAYS, metavar="DAYS",
                       help=f"warn when the calibration is older (default {DEFAULT_MAX_AGE_DAYS:g})")
        p.add_argument("--max-temperature-change-c", type=float, default=DEFAULT_MAX_TEMPERATURE_CHANGE_C, metavar="DEGC",
                       help=f"warn when the recording is this much warmer or colder (default {DEFAULT_MAX_TEMPERATURE_CHANGE_C:g})")


def _add_identity_arguments(p: argparse.ArgumentParser, title: str, when: str, boot_note: str = "",
                            temperature_note: str = "") -> None:
    """--serial, --sensor-model, --boot-count and --temperature: a sensor and the power-up and temperature ``when``."""
    g = p.add_argument_group(title)
    g.add_argument("--serial", default=None, help="the sensor's serial or chip id")
    g.add_argument("--sensor-model", default=None, metavar="MODEL", help="the sensor model, e.g. ICM-20948")
    g.add_argument("--boot-count", type=int, default=None, metavar="N", help=f"the device's power-up count {when}{boot_note}")
    g.add_argument("--temperature", type=float, default=None, metavar="DEGC", help=f"the sensor's temperature {when}{temperature_note}")


def _recording_identity(args: argparse.Namespace, temperature_c: float | None = None) -> SensorIdentity:
    """The recording's identity from the command line (``temperature_c``: the recording's own, when it has one)."""
    from calib.apply.identity import IdentityError

    try:
        return SensorIdentity.from_json({
            "serial": args.serial, "sensor_model": args.sensor_model, "boot_count": args.boot_count,
            "temperature_c": args.temperature if args.temperature is not None else temperature_c})
    except IdentityError as exc:
        flags = {"identity boot_count": "--boot-count", "identity temperature_c": "--temperature"}
        text = str(exc)
        for field, flag in flags.items():
            text = text.replace(field, flag)
        raise ServiceError(text) from None


def _limits(args: argparse.Namespace) -> CalibrationLimits:
    from .config import CalibrationLimits

    limits = CalibrationLimits(getattr(args, "max_age_days", DEFAULT_MAX_AGE_DAYS),
                               getattr(args, "max_temperature_change_c", DEFAULT_MAX_TEMPERATURE_CHANGE_C))
    if not limits.max_age_days > 0:
        raise ServiceError("--max-age-days must be a positive number of days")
    if not limits.max_temperature_change_c > 0:
        raise ServiceError("--max-temperature-change-c must be a positive number of degrees Celsius")
    return limits


def in_force_of(args: argparse.Namespace, store: Any = None, temperature_c: float | None = None) -> Any:
    """The calibration of ``args.device`` in force at ``args.at`` for the recording the arguments describe (None when
    none had been accepted by then); ServiceError when the only ones are another sensor's."""
    from calib.apply.identity import WrongSensor

    from .lifecycle import in_force

    at = _parse_at(args.at)
    recording = _recording_identity(args, temperature_c)
    try:
        return in_force(store or open_store(args.db), args.device, at, _limits(args), recording)
    except WrongSensor as exc:
        raise ServiceError(str(exc)) from None


def register(sub: Any) -> None:
    """Add `gyrocal calibration`."""
    p = sub.add_parser(
        "calibration",
        help="the calibration in force for a device at a moment (default now), with its age and warnings",
        description="Print, as JSON, the device's calibration in force for a recording: one of the recording's power-up when "
        "--boot-count names it, else the latest one accepted at or before --at (default now); never one of another sensor "
        "(--serial, --sensor-model). in_force {at, age_days, chosen_by, identity_check, warnings} says why and warns. Exit 5 "
        "when none had been accepted by then.",
    )
    p.add_argument("device", help="the device's id, as in `gyrocal serve`'s device list")
    add_moment_arguments(p, "ISO 8601 time, e.g. 2026-11-20T14:30 (UTC unless it carries an offset)",
                          DB_URL_HELP)
    p.set_defaults(func=cmd_calibration)


def cmd_calibration(args: argparse.Namespace) -> int:
    from .lifecycle import none_in_force

    cal = in_force_of(args)
    if cal is None:
        print(f"gyrocal: {none_in_force(args.device, args.at)}")
        return EXIT_NONE
    print(json.dumps(cal.model_dump(mode="json"), indent=2))
    return EXIT_OK


def register_apply(sub: Any) -> None:
    """Add `gyrocal apply`."""
    from calib.cli.options import add_reading_arguments

    p = sub.add_parser(
        "apply",
        help="correct a recording with a calibration: the device's in force (--device) or one from a file (--calibration)",
        description="Write FILE corrected by a calibration (g = K (m - G a) + b for the gyroscope; the accelerometer's "
        "model too when the calibration has one) as native CSV, with a JSON sidecar OUT.calibration.json naming the "
        "calibration used and its warnings. --device takes the device's calibration in force at --at (default now) "
        "from the store; --calibration FILE takes gyrocal's calibration JSON ({\"k\": [..], \"b\": [..]} at least) or an "
        "imucal calibration file.",
    )
    add_reading_arguments(p)
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--device", default=None, metavar="ID", help="the device whose calibration in force is applied")
    which.add_argument("--calibration", type=Path, default=None, metavar="FILE", help="gyrocal's calibration JSON or imucal's")
    add_moment_arguments(p, "with --device: when the recording was made (ISO 8601; default now)",
                          "with --device: " + DB_URL_HELP)
    p.add_argument("-o", "--output", type=Path, default=None, metavar="OUT",
                   help="the corrected CSV (default: FILE's name with .calibrated.csv)")
    p.add_argument("--orientation", action="store_true",
                   help="also estimate the orientation before and after correction (Madgwick filter of the ahrs package, or "
                   "gyroscope integration without an accelerometer): OUT.orientation.csv and a plot OUT.orientation.png")
    p.set_defaults(func=cmd_apply)


def cmd_apply(args: argparse.Namespace) -> int:
    from calib.apply.correction import Correction, corrected, read_correction
    from calib.apply.identity import check_identity
    from calib.cli.options import read_recording_args
    from calib.io.readers import write_native_csv

    from .lifecycle import none_in_force, temperature_model

    rec = read_recording_args(args).recording
    used: dict[str, Any]
    model = None
    if args.calibration is not None:
        correction = read_correction(args.calibration)
        recording = _recording_identity(args, rec.mean_temperature_c)
        check = check_identity(correction.identity or SensorIdentity(), recording,
                               max_temperature_change_c=_limits(args).max_temperature_change_c)
        if check.refusal is not None:
            raise ServiceError(f"{args.calibration}: {check.refusal}")
        used = {"file": str(args.calibration), "source": correction.source, "identity_check": check.to_json(),
                "warnings": list(check.warnings)}
    else:
        store = open_store(args.db)
        cal = in_force_of(args, store, temperature_c=rec.mean_temperature_c)
        if cal is None:
            raise ServiceError(f"{none_in_force(args.device, args.at)}: calibrate it first, or give --calibration FILE")
        correction = Correction.from_json(cal.model_dump(mode="json"))
        used = {"calibration_id": cal.id, "device_id": cal.device_id, "accepted_at": cal.accepted_at.isoformat(),
                "operator": cal.operator, "in_force": cal.in_force.model_dump(mode="json"), "warnings": cal.in_force.warnings}
        model = temperature_model(store, cal)
    out = args.output or args.file.with_name(args.file.stem + ".calibrated.csv")
    fixed = corrected(rec, correction)
    if model is not None:
        from calib.apply.temperature import corrected_at_temperature

        how = None
        if rec.temp is not None or args.temperature is not None:
            fixed = corrected_at_temperature(rec, correction, model, args.temperature)
            how = "per sample" if rec.temp is not None else f"at {args.temperature:g} °C"
        used["temperature_model"] = {**model.to_json(), "applied": how}
    write_native_csv(fixed, out)
    if args.orientation:
        used["orientation"] = _write_orientation(rec, fixed, out)
    side = out.with_name(out.name + ".calibration.json") if out.suffix != ".csv" else out.with_suffix(".calibration.json")
    side.write_text(json.dumps({"recording": str(args.file), "corrected": str(out), "calibration": correction.to_json(), **used},
                               indent=2), encoding="utf-8")
    for w in used["warnings"]:
        print(f"gyrocal: warning: {w}")
    print(f"{out} written ({'gyroscope and accelerometer' if correction.A is not None and rec.accel is not None else 'gyroscope'} "
          f"corrected); the calibration used is in {side}")
    if model is not None:
        applied = used["temperature_model"]["applied"]
        print(f"gyrocal: the device's k and b against temperature ({model.watches} watched recording(s)) "
              + (f"applied {applied}" if applied else "not applied: the recording has no temp column; give --temperature"))
    return EXIT_OK


def _write_orientation(rec: Any, calibrated: Any, out: Path) -> dict[str, Any]:
    """OUT.orientation.csv and .png: the orientation before and after correction, with a progress bar."""
    import sys

    from tqdm import tqdm

    from calib.apply.orientation import orientation, plot_orientation

    stem = out.with_suffix("") if out.suffix == ".csv" else out
    with tqdm(total=2 * max(0, len(rec) - 1), desc="orientation", unit="sample", file=sys.stderr, disable=not sys.stderr.isatty()) as bar:
        o = orientation(rec, calibrated, bar.update)
    table = stem.with_name(stem.name + ".orientation.csv")
    table.write_text(o.to_csv(), encoding="utf-8")
    plot = plot_orientation(o, stem.with_name(stem.name + ".orientation.png"))
    final = float(o.difference_deg[-1])
    print(f"orientation written to {table} and {plot}: the calibration moves the final orientation by {final:.1f} deg")
    return {"csv": str(table), "plot": str(plot), "method": o.method, "final_difference_deg": final}


def _parse_at(text: str | None) -> datetime | None:
    if text is None:
        return None
    try:
        return datetime.fromisoformat(text)
    except ValueError:
        raise ServiceError(f"--at {text!r} is not an ISO 8601 time; write it like 2026-11-20T14:30 or 2026-11-20T14:30+01:00") from None


def register_export(sub: Any) -> None:
    """Add `gyrocal export`."""
    p = sub.add_parser(
        "export",
        help="write an accepted calibration for other tools: gyrocal's JSON, imucal's calibration file, or CSV",
        description="Write calibration #ID (or the calibration of --device in force at --at, default now) as gyrocal's "
        "JSON, as an imucal calibration file (imucal.management.load_calibration_info loads it), or as CSV.",
    )
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--id", type=int, default=None, metavar="N", help="the calibration's id (GET /devices/{id}/calibrations)")
    which.add_argument("--device", default=None, metavar="ID", help="the device whose calibration in force is written")
    add_moment_arguments(p, "with --device: the moment (ISO 8601; default now)", DB_URL_HELP,
                          max_age=False)
    p.add_argument("--format", choices=["gyrocal", "imucal", "openvins", "csv"], default="gyrocal",
                   help="openvins: OpenVINS's kalibr_imu_chain.yaml with the intrinsics (needs the accelerometer's calibration; "
                   "add the noise entries from `gyrocal noise REST --kalibr`)")
    p.add_argument("-o", "--output", type=Path, default=None, metavar="OUT", help="the file to write (default: standard output)")
    p.set_defaults(func=cmd_export)


def cmd_export(args: argparse.Namespace) -> int:
    from .export import export_text
    from .lifecycle import none_in_force

    store = open_store(args.db)
    if args.id is not None:
        cal = store.calibration(args.id)
        if cal is None:
            raise ServiceError(f"no calibration #{args.id} in {store.display_url}; `gyrocal calibration DEVICE` names a device's")
    else:
        cal = in_force_of(args, store)
        if cal is None:
            raise ServiceError(none_in_force(args.device, args.at))
    try:
        text, _, _ = export_text(cal, args.format)
    except GyrocalError as exc:
        raise ServiceError(f"calibration #{cal.id} cannot be written for {args.format}: {exc}") from None
    if args.output is None:
        print(text)
        return EXIT_OK
    try:
        args.output.write_text(text if text.endswith("\n") else text + "\n", encoding="utf-8")
    except OSError as exc:
        raise ServiceError(f"cannot write {args.output} ({exc.strerror or exc}); check the folder exists and is writable") from None
    print(f"calibration #{cal.id} of {cal.device_id} written to {args.output} ({args.format})")
    return EXIT_OK


def register_import(sub: Any) -> None:
    """Add `gyrocal import`."""
    p = sub.add_parser(
        "import",
        help="add a calibration made elsewhere (an imucal calibration file or gyrocal's JSON) to a device's history",
        description="Read FILE (imucal's Ferraris calibration file, or gyrocal's calibration JSON) and add it to the device's "
        "history, marked as imported: it becomes the device's calibration in force from now, as an accepted one does. "
        "The same file is imported once per device.",
    )
    p.add_argument("file", type=Path, help="the calibration file (JSON)")
    p.add_argument("--device", required=True, metavar="ID", help="the device it calibrates")
    p.add_argument("--operator", required=True, metavar="NAME", help="who imports it (an operator of the store; `gyrocal operator list`)")
    p.add_argument("--db", default=None, metavar="URL", help=DB_URL_HELP)
    _add_identity_arguments(p, "the sensor it was measured on, when the file does not say", "when it was measured")
    p.set_defaults(func=cmd_import)


def cmd_import(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from calib import __version__
    from calib.apply.correction import read_correction

    from .store import NotAcceptable, sha256_hex

    correction = read_correction(args.file)
    stated = _recording_identity(args)
    correction = replace(correction, identity=(correction.identity or SensorIdentity()).completed(stated))
    store = open_store(args.db)
    require_active_operator(store, args.operator)
    try:
        rec = store.import_calibration(args.device, correction, args.operator, __version__, file_name=args.file.name,
                                       file_sha256=sha256_hex(args.file.read_bytes()))
    except NotAcceptable as exc:
        raise ServiceError(str(exc)) from None
    print(f"{args.file} imported for {args.device} as calibration #{rec.id} ({correction.source}); it is in force from "
          f"{rec.accepted_at.isoformat(timespec='seconds')}")
    return EXIT_OK
