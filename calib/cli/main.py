"""The ``gyrocal`` command line.

Subcommands of calib itself (calibrate, simulate, bench, demo) live here; the service and the
simulated wearable add theirs through the ``gyrocal.commands`` entry-point group, so that this
package imports nothing else of gyrocal's.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import sys
from collections.abc import Callable, Sequence
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any

import numpy as np

from calib import __version__
from calib.blas import single_threaded_blas
from calib.cli.lazy_help import lazy_help
from calib.cli.options import writable as _writable
from calib.cli.summary import fmt_vec, result_summary
from calib.errors import GyrocalError
from calib.extras import missing_module, register_unavailable

EXIT_OK = 0
EXIT_USAGE = 2  # bad arguments or bad input file
EXIT_PROTOCOL = 3  # the recording was read and is refused: the protocol is not in it, or it does not determine the calibration
EXIT_INTERNAL = 70
OUR_PACKAGES = ("calib", "server", "mock_device", "wearable_protocol", "webui")


def cmd_calibrate(args: argparse.Namespace) -> int:
    from calib.cli.options import error_json, read_recording_args
    from calib.errors import CalibrationError, GyrocalError, RecordingError, Refusal, error_code
    from calib.pipeline import calibrate_protocol, method_options

    if args.plot:
        _writable(args.plot, "plot")
    method_options(args.method, args.heading_prior_deg)
    try:
        read = read_recording_args(args)
    except GyrocalError as exc:
        if args.json:
            print(error_json(exc, error_code(exc) if isinstance(exc, RecordingError) else "bad_recording", []))
        raise
    rec = read.recording
    try:
        try:
            result, protocol = calibrate_protocol(rec, read.protocol, args.method, read.sections,
                                                  heading_prior_deg=args.heading_prior_deg)
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
        print(json.dumps({**result.to_json(), "protocol": protocol, "accelerometer": result.quality.get("accelerometer")}))
    else:
        print(result_summary(result, str(args.file)))
        if args.plot:
            print(f"plot saved to {args.plot}")
    return EXIT_OK


def _parse_effect(spec: str) -> tuple[str, str]:
    if "=" not in spec:
        return spec, ""
    name, value = spec.split("=", 1)
    return name.strip(), value.strip()


def cmd_simulate(args: argparse.Namespace) -> int:
    from calib.simulator import extended_script_for_seed, simulate

    if args.protocol == "study":
        return _simulate_study(args)
    kwargs: dict[str, Any] = {"seed": args.seed, "noise": args.noise, "fs": args.fs}
    if args.protocol == "extended":
        kwargs["script"] = extended_script_for_seed(args.seed)
    if args.full_scale is not None:
        kwargs["full_scale_dps"] = args.full_scale
    if args.effect:
        from calib.effects import parse_effect

        kwargs["effects"] = [parse_effect(*_parse_effect(s)) for s in args.effect]
    rec, truth = simulate(**kwargs)
    return _write_simulated(args, rec, truth.to_dict())


def _write_simulated(args: argparse.Namespace, rec: Any, truth: dict[str, Any]) -> int:
    """Write a simulated recording to ``--output``; print its truth as JSON (``--truth``) or what was written."""
    from calib.io.readers import write_native_csv

    write_native_csv(rec, args.output)
    if args.truth:
        print(json.dumps(truth))
    else:
        print(f"wrote {len(rec)} samples ({rec.duration_s:.1f} s at {args.fs:g} Hz) to {args.output}", file=sys.stderr)
    return EXIT_OK


def _simulate_study(args: argparse.Namespace) -> int:
    """`simulate --protocol study`: a study day (calib.simulator.study_day)."""
    from calib.effects.base import SimulationConfigError
    from calib.simulator.study_day import simulate_study_day

    if args.effect or args.full_scale is not None:
        raise SimulationConfigError("--protocol study simulates its own sensor (warming on the skin, --event): it takes no "
                                    "--effect or --full-scale")
    if not args.duration > 60.0:
        raise SimulationConfigError(f"--duration must be more than 60 s; got {args.duration:g}")
    rec, day = simulate_study_day(args.seed, args.duration, args.fs, args.noise, temperature_channel=not args.no_temperature,
                                  event=args.event, event_size=args.event_size)
    return _write_simulated(args, rec, day.to_dict())


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
    print(result_summary(result, f"a simulated recording (seed {args.seed}, noise {args.noise} deg/s)"))
    print("")
    print(f"simulated truth  k = {fmt_vec(truth.k, 6)}")
    print(f"                 b = {fmt_vec(truth.b, 4)} deg/s")
    print(f"error            k = {fmt_vec(np.asarray(result.k) - truth.k, 6)}")
    print(f"                 b = {fmt_vec(np.asarray(result.b) - truth.b, 4)} deg/s")
    return EXIT_OK


EFFECT_VALUES = "{effect values}"  # in a help text: every registered effect's NAME=VALUE, filled in when help is shown


def _effect_values() -> str:
    from calib.effects.tables import effect_value_help

    return effect_value_help()


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser, with the subcommands other gyrocal packages register."""
    parser = argparse.ArgumentParser(
        prog="gyrocal",
        description="In-field gyroscope calibration: rest, then one full hand turn about each axis.",
    )
    parser.add_argument("--version", action="version", version=f"gyrocal {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    from calib.cli.diagnose import add_diagnose_parser
    from calib.cli.kit import add_kit_parsers
    from calib.cli.noise import add_noise_parser
    from calib.cli.options import add_recording_arguments
    from calib.estimators.closure.placement import HEADING_PRIOR_DEG
    from calib.estimators.registry import DEFAULT_METHOD, method_names

    p = sub.add_parser("calibrate", help="calibrate a recording (CSV) of the protocol")
    add_recording_arguments(p)
    p.add_argument("--method", choices=method_names(), default=DEFAULT_METHOD, help=f"estimator (default {DEFAULT_METHOD})")
    p.add_argument("--heading-prior-deg", type=float, default=None, metavar="DEG",
                   help="how far (1 sigma, deg) the device's heading may be off after each turn when put back against the "
                        f"block; the accelerometer cannot see it (closure method; default {HEADING_PRIOR_DEG:g})")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the summary")
    p.add_argument("--plot", type=Path, default=None, help="save a PNG of the rate magnitude and angles before/after calibration")
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("simulate", help="simulate a recording of the protocol",
                       formatter_class=lazy_help(EFFECT_VALUES, _effect_values))
    p.add_argument("--seed", type=int, required=True)
    p.add_argument("--noise", type=float, default=0.03, help="white noise std on the readings, deg/s (default 0.03)")
    p.add_argument("--fs", type=float, default=104.0, help="sample rate, Hz (default 104)")
    p.add_argument("--full-scale", type=float, default=None, help="gyro full scale, deg/s: readings clip there")
    p.add_argument("--protocol", choices=("paper", "extended", "study"), default="paper",
                   help="paper: one turn about each axis (default); extended: each axis turned both ways, slowly and "
                        "fast (12 turns, about 90 s), which reveals scale asymmetry and nonlinearity; study: a study day "
                        "compressed (the table, lying, sitting, standing, walking bouts) on a thigh warming on the skin, "
                        "with a temperature column; its calibration is the truth's k and b at temp_cal_c")
    p.add_argument("--duration", type=float, default=3600.0, help="with --protocol study: the day's length, s (default 3600)")
    p.add_argument("--event", choices=("k", "b"), default=None,
                   help="with --protocol study: a drop at a random time changes one axis's k (0.2-1 %%) or b (0.05-0.5 deg/s)")
    p.add_argument("--event-size", type=float, default=None, metavar="SIZE",
                   help="with --event: its size (relative for k, deg/s for b; a random sign)")
    p.add_argument("--no-temperature", action="store_true", help="with --protocol study: no temperature column (it still warms)")
    p.add_argument(
        "--effect",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help=(
            "add a physical effect (repeatable; `gyrocal effects` lists them); one number applies to all axes. "
            + EFFECT_VALUES
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
    add_noise_parser(sub)
    add_kit_parsers(sub)

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
    single_threaded_blas()
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


def run() -> None:
    """The ``gyrocal`` command: ``main``, then exit without the collector walking everything the command loaded (a
    third of a second of every command's end). ``main`` itself may run in a long-lived process, which must not freeze."""
    code = main()
    gc.freeze()
    sys.exit(code)


if __name__ == "__main__":
    run()
