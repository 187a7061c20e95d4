"""The ``gyrocal`` command line.

Subcommands of calib itself (calibrate, simulate, bench, demo) live here; the service and the
simulated wearable add theirs through the ``gyrocal.commands`` entry-point group, so that this
package imports nothing else of gyrocal's.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable, Sequence
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any

import numpy as np

from calib import __version__
from calib.errors import GyrocalError
from calib.extras import missing_module, register_unavailable

EXIT_OK = 0
EXIT_USAGE = 2  # bad arguments or bad input file
EXIT_PROTOCOL = 3  # the recording was read and is refused: the protocol is not in it, or it does not determine the calibration
EXIT_INTERNAL = 70
OUR_PACKAGES = ("calib", "server", "mock_device", "wearable_protocol", "webui")


def _fmt_vec(v: Sequence[float] | np.ndarray | None, digits: int = 5) -> str:
    if v is None:
        return "-"
    return "[" + ", ".join(f"{x:+.{digits}f}" for x in v) + "]"


def _summary(result: Any, source: str) -> str:
    """A readable summary of a CalibrationResult."""
    d = result.to_dict()
    lines = [f"gyrocal {__version__} — calibration of {source} (method: {d['method']})", ""]
    proto = (d.get("quality") or {}).get("protocol")
    if proto:
        lines += [f"Protocol found: {proto['found']['name']} — {proto['found']['summary']}; used: {proto['used']}"
                  + (f" ({proto['sections']} labelled sections)" if proto.get("sections") else ""), ""]
    lines.append("Stages found:")
    residuals = _gravity_residuals_by_motion(d.get("quality") or {})
    for s in d["stages"]:
        extra = ""
        if s["kind"] == "turn":
            extra = f"  about {s['axis']}, {s['angle_deg']:+.1f} deg"
        if s["kind"] != "still":
            extra += next((residuals.pop(span) for span in list(residuals)
                           if span[0] - 1e-6 <= s["start_s"] and s["end_s"] <= span[1] + 1e-6), "")
        flags = f"  [{', '.join(s['flags'])}]" if s["flags"] else ""
        lines.append(f"  {s['kind']:<7} {s['start_s']:8.2f} – {s['end_s']:8.2f} s{extra}{flags}")
    lines.append("")
    unc = d.get("uncertainty") or {}
    bound = d.get("bound") or {}
    lines.append("Model g = K m + b  (g true rate, m reading, deg/s)")
    lines.append(f"{'':4}{'value':>12}{'std':>12}{'bound':>12}")
    for name, key, digits in (("k", "k", 6), ("b", "b", 4)):
        for i, axis in enumerate("xyz"):
            std = unc.get(key)
            bnd = bound.get(key)
            unit = "" if key == "k" else " deg/s"
            lines.append(
                f"{name}_{axis:<2}{d[key][i]:>12.{digits}f}"
                f"{(f'{std[i]:.2g}' if std else '-'):>12}"
                f"{(f'{bnd[i]:.2g}' if bnd else '-'):>12}{unit}"
            )
    if d.get("K") is not None:
        lines.append("Full calibration matrix K:")
        lines.extend("  " + _fmt_vec(row, 6) for row in d["K"])
    if d.get("G") is not None:
        lines.append("g-sensitivity G of g = K (m - G a) + b, (deg/s)/g (row: gyro axis, column: acceleration axis):")
        lines.extend("  " + _fmt_vec(row, 4) for row in d["G"])
    q = d.get("quality") or {}
    lines.extend(_g_sensitivity_lines(q.get("g_sensitivity")))
    lines.extend(_constraint_lines(q))
    if d.get("noise_dps"):
        lines.append(f"Noise (from the stills): {_fmt_vec(d['noise_dps'], 4)} deg/s")
    if q:
        shown = (f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in q.items() if not isinstance(v, (dict, list)))
        lines.append("Quality: " + ", ".join(shown))
    for w in d.get("warnings") or []:
        lines.append(f"warning: {w}")
    return "\n".join(lines)


def _g_sensitivity_lines(test: dict[str, Any] | None) -> list[str]:
    """What the g-sensitivity test found, and the fit without it (multi-position)."""
    if not test:
        return []
    without = test.get("without") or {}
    rms = without.get("gravity_residual_rms_deg")
    before = f"; without it: Birge ratio {without['birge_ratio']:.2f}"
    if rms is not None:
        before += f", gravity residuals {rms:.3f} deg rms"
    return [f"g-sensitivity {'fitted' if test.get('fitted') else 'not fitted'}: {test.get('reason', '')}" + before]


def _gravity_residuals_by_motion(q: dict[str, Any]) -> dict[tuple[float, float], str]:
    """Each re-orientation's gravity residual after calibration (multi-position), as printed beside its motion,
    keyed by the motion's [start, end] s."""
    spans, deg, z = q.get("gravity_motions_s") or [], q.get("gravity_residual_deg") or [], q.get("gravity_z") or []
    return {(a, b): f"  gravity residual {r:.3f} deg (chi-square {zz**2:.1f} for 2)"
            for (a, b), r, zz in zip(spans, deg, z, strict=False)}


def _constraint_lines(q: dict[str, Any]) -> list[str]:
    """Each kind of constraint's chi-square against what noise explains, the accelerometer's noise floor, the gyro's
    noise while moving and the rests still settling (multi-position)."""
    out = []
    fits = q.get("constraint_fit") or {}
    if fits:
        shown = (f"{kind.replace('_', ' ')} {f['chi2']:.1f} / {f['expected']:.1f} = {f['ratio']:.2f} (p {f['p_value']:.2g})"
                 for kind, f in fits.items() if f.get("ratio") is not None)
        out.append("Chi-square per constraint / what the noise explains: " + "; ".join(shown))
    floor = q.get("accelerometer_floor") or {}
    if floor.get("measured"):
        axes = ", ".join(f"{axis} {mg:.3f}" if mg > 0 else f"{axis} none" for axis, mg in zip("xyz", floor["per_axis_mg"], strict=True))
        out.append(f"Accelerometer noise floor (rest means' scatter beyond white noise, measured on rest {floor['rest']} "
                   f"over {floor['tau_s']:.1f} s spans): {axes} mg")
    elif floor:
        from calib.noise.accel_floor import MIN_SPANS

        out.append(f"Accelerometer noise floor: not measured (no rest holds {MIN_SPANS} spans of a typical rest's length); "
                   "rest means counted as white noise only")
    moving = q.get("gyro_motion_noise") or {}
    if moving.get("measured"):
        lo, hi = moving["band_hz"]
        axes = ", ".join(f"{axis} {r:.2f}" + ("" if c != 1.0 else " (within chance, not counted)")
                         for axis, r, c in zip("xyz", moving["variance_ratio"], moving["counted"], strict=True))
        out.append(f"Gyroscope noise while moving over at rest (variance, {lo:.0f}-{hi:.0f} Hz): {axes}")
    elif moving:
        out.append(f"Gyroscope noise while moving: not measured ({moving.get('reason') or 'no reason given'}); "
                   "motions counted with the rests' noise")
    settling = q.get("settling") or {}
    if settling.get("drift_deg"):
        out.append(f"Rests still settling (counted in their noise): {len(settling['rests_counted'])} of "
                   f"{len(settling['drift_deg'])}, largest drift {settling['largest_deg']:.3f} deg")
    return out


def _writable(path: Path, what: str) -> Path:
    """``path`` if a file can be written there, else OutputError saying why (checked before any work is done)."""
    from calib.errors import OutputError

    folder = path.expanduser().resolve().parent
    if not folder.is_dir():
        raise OutputError(f"cannot write the {what} to {path}: the folder {folder} does not exist; create it or choose another path")
    if not os.access(folder, os.W_OK):
        raise OutputError(f"cannot write the {what} to {path}: the folder {folder} is not writable")
    if path.is_dir():
        raise OutputError(f"cannot write the {what} to {path}: that is a folder; give a file name such as {path / 'plot.png'}")
    return path


def cmd_calibrate(args: argparse.Namespace) -> int:
    from calib.cli.options import error_json, read_recording_args
    from calib.errors import CalibrationError, GyrocalError, RecordingError, Refusal, error_code
    from calib.pipeline import calibrate_protocol

    if args.plot:
        _writable(args.plot, "plot")
    try:
        read = read_recording_args(args)
    except GyrocalError as exc:
        if args.json:
            print(error_json(exc, error_code(exc) if isinstance(exc, RecordingError) else "bad_recording", []))
        raise
    rec = read.recording
    try:
        try:
            result, protocol = calibrate_protocol(rec, read.protocol, args.method, read.sections)
        except Refusal:
            raise
        except GyrocalError as exc:  # the file was read: whatever else stops the calibration refuses this recording
            raise CalibrationError(str(exc), code="not_calibrated") from None
    except Refusal as exc:
        from calib.stages.detector import detect_stages

        stages = exc.stages or detect_stages(rec)
        if args.plot:
            from calib.plots import plot_stages

            plot_stages(rec, stages, args.plot, f"{args.file}: not calibrated. {exc}")
            print(f"the stages found are drawn in {args.plot}", file=sys.stderr)
        if args.json:
            print(error_json(exc, exc.code, stages))
        raise
    if args.plot:
        from calib.plots import plot_calibration

        plot_calibration(rec, result, args.plot)
    if args.json:
        print(json.dumps({**result.to_dict(), "protocol": protocol, "accelerometer": result.quality.get("accelerometer")}))
    else:
        print(_summary(result, str(args.file)))
        if args.plot:
            print(f"plot saved to {args.plot}")
    return EXIT_OK


def _parse_effect(spec: str) -> tuple[str, str]:
    if "=" not in spec:
        return spec, ""
    name, value = spec.split("=", 1)
    return name.strip(), value.strip()


def cmd_simulate(args: argparse.Namespace) -> int:
    from calib.io.readers import write_native_csv
    from calib.simulator import extended_protocol_script, simulate

    kwargs: dict[str, Any] = {"seed": args.seed, "noise": args.noise, "fs": args.fs}
    if args.protocol == "extended":
        # the script's own draws (durations, tilts, profiles) from a stream of their own, as simulate's are
        kwargs["script"] = extended_protocol_script(np.random.default_rng([args.seed, 1]))
    if args.full_scale is not None:
        kwargs["full_scale_dps"] = args.full_scale
    if args.effect:
        from calib.effects import parse_effect

        kwargs["effects"] = [parse_effect(*_parse_effect(s)) for s in args.effect]
    rec, truth = simulate(**kwargs)
    write_native_csv(rec, args.output)
    if args.truth:
        print(json.dumps(truth.to_dict()))
    else:
        print(f"wrote {len(rec)} samples ({rec.duration_s:.1f} s at {args.fs:g} Hz) to {args.output}", file=sys.stderr)
    return EXIT_OK


def cmd_effects(args: argparse.Namespace) -> int:
    """The catalogue of physical effects: model, ``--effect`` value, drawn range and what reveals each."""
    from calib.effects import EFFECTS, catalogue_specs

    specs = catalogue_specs()
    if args.json:
        rows = [{"name": n, "model": s.equation, "parameters": s.parameters, "value": EFFECTS[n].usage,
                 "drawn": {"low": s.drawn.low, "high": s.drawn.high, "unit": s.drawn.unit, "what": s.drawn.what},
                 "typical": s.typical_text or None, "revealed_by": s.reveal} for n, s in specs.items()]
        print(json.dumps(rows))
        return EXIT_OK
    for name, spec in specs.items():
        print(f"{name}\n  model:       {spec.equation}\n  --effect:    {name}={EFFECTS[name].usage}\n"
              f"  drawn:       {spec.drawn.text()} ({spec.drawn.what})\n  revealed by: {spec.reveal}")
    return EXIT_OK


def cmd_bench(args: argparse.Namespace) -> int:
    from calib.studies.paper_sim import paper_sim

    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    report = paper_sim(
        sets=args.sets,
        runs_per_set=args.runs_per_set,
        noise_levels=tuple(args.noise),
        methods=methods,
        seed=args.seed,
        progress=not args.no_progress,
        plot_path=args.plot,
        workers=args.workers,
    )
    return _print_report(report, args)


def _print_report(report: Any, args: argparse.Namespace) -> int:
    """A benchmark's report: JSON with --json, else its table and where the plot went."""
    if args.json:
        print(json.dumps(report.to_dict()))
    else:
        print(report.table())
        if args.plot:
            print(f"plot saved to {args.plot}")
    return EXIT_OK


def cmd_bench_methods(args: argparse.Namespace) -> int:
    """The paper's comparison of calibration methods (Tables 2-3), on simulated sensors."""
    from calib.studies.methods import METHODS, compare_methods

    names = [m.strip() for m in args.methods.split(",") if m.strip()] if args.methods else None
    known = [m.name for m in METHODS]
    if names and (bad := [n for n in names if n not in known]):
        from calib.errors import GyrocalError

        raise GyrocalError(f"unknown method(s) {', '.join(bad)}: choose from {', '.join(known)}")
    if args.runs < 1:
        from calib.errors import GyrocalError

        raise GyrocalError("--runs must be at least 1")
    if args.plot:
        _writable(args.plot, "plot")
    report = compare_methods(runs=args.runs, noise_levels=tuple(args.noise), seed=args.seed, progress=not args.no_progress,
                             plot_path=args.plot, methods=names)
    return _print_report(report, args)


def cmd_demo(args: argparse.Namespace) -> int:
    """Simulate one recording of the protocol, calibrate it and compare with the truth."""
    from calib.pipeline import calibrate
    from calib.simulator import simulate

    rec, truth = simulate(seed=args.seed, noise=args.noise)
    result = calibrate(rec)
    print(_summary(result, f"a simulated recording (seed {args.seed}, noise {args.noise} deg/s)"))
    print("")
    print(f"simulated truth  k = {_fmt_vec(truth.k, 6)}")
    print(f"                 b = {_fmt_vec(truth.b, 4)} deg/s")
    print(f"error            k = {_fmt_vec(np.asarray(result.k) - truth.k, 6)}")
    print(f"                 b = {_fmt_vec(np.asarray(result.b) - truth.b, 4)} deg/s")
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser, with the subcommands other gyrocal packages register."""
    parser = argparse.ArgumentParser(
        prog="gyrocal",
        description="In-field gyroscope calibration: rest, then one full hand turn about each axis.",
    )
    parser.add_argument("--version", action="version", version=f"gyrocal {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    from calib.cli.diagnose import add_diagnose_parser
    from calib.cli.options import add_recording_arguments
    from calib.estimators.registry import DEFAULT_METHOD, method_names

    p = sub.add_parser("calibrate", help="calibrate a recording (CSV) of the protocol")
    add_recording_arguments(p)
    p.add_argument("--method", choices=method_names(), default=DEFAULT_METHOD, help=f"estimator (default {DEFAULT_METHOD})")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the summary")
    p.add_argument("--plot", type=Path, default=None, help="save a PNG of the rate magnitude and angles before/after calibration")
    p.set_defaults(func=cmd_calibrate)

    from calib.effects.tables import effect_value_help

    p = sub.add_parser("simulate", help="simulate a recording of the protocol")
    p.add_argument("--seed", type=int, required=True)
    p.add_argument("--noise", type=float, default=0.03, help="white noise std on the readings, deg/s (default 0.03)")
    p.add_argument("--fs", type=float, default=104.0, help="sample rate, Hz (default 104)")
    p.add_argument("--full-scale", type=float, default=None, help="gyro full scale, deg/s: readings clip there")
    p.add_argument("--protocol", choices=("paper", "extended"), default="paper",
                   help="paper: one turn about each axis (default); extended: each axis turned both ways, slowly and "
                        "fast (12 turns, about 90 s), which reveals scale asymmetry and nonlinearity")
    p.add_argument(
        "--effect",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help=(
            "add a physical effect (repeatable; `gyrocal effects` lists them); one number applies to all axes. "
            + effect_value_help().replace("%", "%%")
        ),
    )
    p.add_argument("-o", "--output", type=Path, required=True, help="native CSV to write")
    p.add_argument("--truth", action="store_true", help="print the simulated truth as JSON")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("effects", help="list the physical effects the simulator and the diagnosis know")
    p.add_argument("--json", action="store_true", help="print one JSON list instead of the text")
    p.set_defaults(func=cmd_effects)

    p = sub.add_parser("bench", help="benchmarks")
    bsub = p.add_subparsers(dest="bench", metavar="BENCH", required=True)
    b = bsub.add_parser("paper-sim", help="the paper's simulation study (Section 3, Fig. 7)")
    b.add_argument("--sets", type=int, default=30, help="parameter sets (default 30)")
    b.add_argument("--runs-per-set", type=int, default=500, help="runs per set (default 500)")
    b.add_argument("--noise", type=float, nargs="+", default=[0.03, 0.15], help="noise levels, deg/s")
    b.add_argument("--methods", default="paper,closure", help="comma-separated estimators (default paper,closure)")
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1), help="processes (default: up to 2)")
    b.add_argument("--plot", type=Path, default=Path("paper-sim.png"), help="box plot PNG (default paper-sim.png)")
    b.add_argument("--json", action="store_true", help="print the report as JSON")
    b.add_argument("--no-progress", action="store_true", help="no progress bar")
    b.set_defaults(func=cmd_bench)

    b = bsub.add_parser("methods", help="the paper's comparison of methods (Tables 2-3): turntable, accelerometer-aided, "
                        "servomotor, Ferraris, the paper's Algorithm 1 and gyrocal on the same simulated sensors")
    b.add_argument("--runs", type=int, default=20, help="runs per method, sensor and noise level (default 20)")
    b.add_argument("--noise", type=float, nargs="+", default=[0.03, 0.15], help="gyro noise levels, deg/s")
    b.add_argument("--methods", default=None, help="comma-separated subset (default: all)")
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--plot", type=Path, default=Path("methods.png"), help="bar chart PNG (default methods.png)")
    b.add_argument("--json", action="store_true", help="print the report as JSON")
    b.add_argument("--no-progress", action="store_true", help="no progress bar")
    b.set_defaults(func=cmd_bench_methods)

    add_diagnose_parser(sub)

    p = sub.add_parser("demo", help="simulate a recording, calibrate it and compare with the truth")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--noise", type=float, default=0.03)
    p.set_defaults(func=cmd_demo)

    for ep in entry_points(group="gyrocal.commands"):
        try:
            register: Callable[[Any], None] = ep.load()
        except ImportError as exc:
            register_unavailable(sub, ep.name, exc)  # that part of gyrocal is not installed: say so when it is asked for
            continue
        register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code. Errors are printed as plain messages, never tracebacks."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_USAGE
    try:
        return int(args.func(args) or 0)
    except GyrocalError as exc:
        from calib.errors import Refusal

        print(f"gyrocal: error: {exc}", file=sys.stderr)
        return EXIT_PROTOCOL if isinstance(exc, Refusal) else EXIT_USAGE
    except ImportError as exc:
        if (exc.name or "").split(".")[0] in OUR_PACKAGES:
            raise  # a fault of gyrocal's own, not a missing install
        print(f"gyrocal: error: {missing_module(args.command, exc)}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("gyrocal: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return EXIT_OK
    except Exception as exc:  # the last line of defence: a message, not a traceback
        if os.environ.get("GYROCAL_DEBUG"):
            raise
        print(
            f"gyrocal: internal error ({type(exc).__name__}: {exc}). "
            "Run again with GYROCAL_DEBUG=1 for details and report it.",
            file=sys.stderr,
        )
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
