"""``gyrocal diagnose``: compare a recording with its simulation and name the physics the model leaves out."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from calib import __version__
from calib.cli.options import add_recording_arguments, read_recording_args


def add_diagnose_parser(sub: Any) -> None:
    """Register ``diagnose`` on the subcommand parsers ``sub``."""
    p = sub.add_parser("diagnose", help="compare a recording with its simulation and name the physics the model leaves out")
    add_recording_arguments(p)
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the summary")
    p.add_argument("--report", type=Path, default=None, metavar="DIR", help="write an HTML report with plots into DIR")
    p.add_argument("--max-samples", type=int, default=500_000, metavar="N",
                   help="refuse recordings of more samples (counting lost ones put back): a diagnosis needs about 13 kB "
                   "of memory a sample (default 500000)")
    p.set_defaults(func=cmd_diagnose)


def cmd_diagnose(args: argparse.Namespace) -> int:
    """Diagnose the recording on the command line; print the summary or the JSON."""
    from tqdm import tqdm

    from calib.diagnosis import diagnose

    read = read_recording_args(args)
    with tqdm(total=100, desc="diagnose", unit="%", file=sys.stderr, disable=args.json and not sys.stderr.isatty()) as bar:

        def progress(fraction: float, stage: str) -> None:
            bar.set_postfix_str(stage, refresh=False)
            bar.update(round(100 * fraction) - bar.n)

        diag = diagnose(read.recording, progress=progress, max_samples=args.max_samples, protocol=read.protocol,
                        sections=read.sections)
    if args.report:
        from calib.diagnosis.report import write_report

        path = write_report(diag, args.report, title=str(args.file))
        print(f"report written to {path}", file=sys.stderr)
    if args.json:
        print(json.dumps(diag.to_dict()))
    else:
        print(diagnosis_summary(diag.to_dict(), str(args.file)))
    return 0


def diagnosis_summary(d: dict[str, Any], source: str) -> str:
    """The diagnosis for people: protocol, effects found, what is left unexplained, the worst mismatches."""
    lines = [f"gyrocal {__version__} — diagnosis of {source}", ""]
    proto = d.get("info", {}).get("protocol")
    if proto:
        lines += [f"Protocol: {proto['found']['summary']}; diagnosed as {proto['used']}", ""]
    if d["effects"]:
        lines.append("Effects (most important first; fit: lower is better):")
        for e in d["effects"]:
            lines.append(f"  {e['name']:<20} fit {e['fit']['before']:.4g} -> {e['fit']['after']:.4g}")
            lines.append(f"      {e['evidence'].get('summary', '')}")
            lines += [f"      told apart from {t['rival']}: {t['summary']}" for t in e["evidence"].get("rivals", [])]
    else:
        lines.append("The nominal model explains the recording: no catalogued effect is needed.")
    for u in d["unexplained"]:
        lines.append(f"unexplained: {u.get('description', '')}")
    if d["mismatches"]:
        lines.append("")
        lines.append("Mismatches against the nominal simulation:")
        for m in d["mismatches"][:10]:
            lines.append(f"  {m['where']}: {m['statistic']} = {m['observed']:.4g} (simulated {m['simulated_range'][0]:.3g} "
                         f"to {m['simulated_range'][1]:.3g}, p = {m['p_value']:.2g})")
    for n in d["not_identifiable"]:
        lines.append(f"{n['name']}: {n['reason']}")
    return "\n".join(lines)
