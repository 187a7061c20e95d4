"""The simulated wearables' options of `gyrocal serve` (--mock and its kin): what they are, and what is wrong with a
choice of them, in words (the command raises it)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from calib.simulator.kit import TrayFaults


def add_mock_options(p: Any) -> None:
    """Add --mock and its options to `gyrocal serve`'s parser ``p``."""
    p.add_argument("--mock", type=int, default=0, metavar="N", help="add N simulated wearables mock-1 ... mock-N")
    p.add_argument("--mock-first", type=int, default=1, metavar="I",
                   help="number the simulated wearables from mock-I (default 1): gateways of one fleet sharing some wearables")
    p.add_argument(
        "--mock-speed", type=float, default=1.0, metavar="X", help="simulated time runs X times faster than real time (default 1)"
    )
    p.add_argument("--mock-seed", type=int, default=0, metavar="S", help="seed of the simulated sensors and clinicians (default 0)")
    p.add_argument(
        "--mock-scenario",
        default="normal",
        metavar="NAMES",
        help="what the simulated clinician does, comma-separated, assigned to mock-1, mock-2, ... in turn: "
        "normal, moved_during_still, wrong_axis, too_fast, stops_short, link_drop, packet_loss, dropped (a fixed script), or "
        "hand:careful, hand:hurried, hand:sloppy, hand:bumps, hand:gauge, hand:short (a clinician who follows the session's prompts, "
        "reading them from the service as the page does) (default normal)",
    )
    p.add_argument(
        "--mock-rate", type=float, default=None, metavar="HZ",
        help="sample rate of the simulated wearables (default: the model's streaming rate, 104 for gyrocal)"
    )
    p.add_argument(
        "--mock-model", default="gyrocal", metavar="NAME",
        help="the protocol the simulated wearables speak: gyrocal, polar-pmd, metawear, thingy52 or movella-dot (default gyrocal)"
    )
    p.add_argument("--mock-kit", action="store_true",
                   help="the N simulated wearables ride in one tray that one clinician turns through the protocol: a kit to "
                        "calibrate together (POST /kits/calibrate); a scripted clinician, or with --mock-scenario hand:STYLE "
                        "one who follows the kit's prompts")
    p.add_argument("--mock-kit-loose", type=int, default=None, metavar="I",
                   help="with --mock-kit: the I-th simulated wearable (from 1) slips in its slot during the second turn")
    # calib.simulator.kit.SLIP_WHEN, written out: importing it would load scipy at every start of the command line
    p.add_argument("--mock-kit-loose-in", choices=("turn", "pause"), default="turn",
                   help="with --mock-kit-loose: it slips during the second turn (default), or in the pause after it, the "
                        "tray resting still")
    p.add_argument("--mock-kit-drop", type=int, default=None, metavar="I",
                   help="with --mock-kit: the I-th simulated wearable (from 1) goes out of range for 1.5 s in the first turn")
    p.add_argument("--mock-kit-out", type=int, default=None, metavar="I",
                   help="with --mock-kit: the I-th simulated wearable (from 1) lies on the table beside the tray, switched "
                        "on: it turns with nothing")
    p.add_argument("--mock-kit-misalignment", type=float, default=0.0, metavar="M",
                   help="with --mock-kit: the simulated sensors' axes are not orthogonal, the entries above each one's "
                        "K's diagonal drawn in +-M (e.g. 0.01: 1 %% cross-axis sensitivity)")


def mock_problem(args: argparse.Namespace) -> str | None:
    """What is wrong with the simulated wearables' numbers and the kit's options; None when nothing is."""
    if args.mock < 0 or args.mock > 1000:
        return "--mock takes a number of simulated wearables between 0 and 1000"
    if not 1 <= args.mock_first <= 100000:
        return "--mock-first takes the first simulated wearable's number, from 1 to 100000"
    if not (args.mock_speed > 0):
        return "--mock-speed must be a positive number (1 = real time)"
    if args.mock_kit and args.mock < 2:
        return "--mock-kit puts the simulated wearables in one tray: give at least two with --mock N"
    for flag, value in (("--mock-kit-loose", args.mock_kit_loose), ("--mock-kit-drop", args.mock_kit_drop),
                        ("--mock-kit-out", args.mock_kit_out)):
        if value is not None and not (args.mock_kit and 1 <= value <= args.mock):
            return f"{flag} names one of the kit's simulated wearables, from 1 to {args.mock}, with --mock-kit"
    if args.mock_kit_out is not None and args.mock_kit_out in (args.mock_kit_loose, args.mock_kit_drop):
        return ("--mock-kit-out's wearable lies beside the tray: it cannot slip in its slot (--mock-kit-loose) or "
                "be the one whose link drops in a turn (--mock-kit-drop); name another")
    if args.mock_kit_loose_in != "turn" and args.mock_kit_loose is None:
        return "--mock-kit-loose-in says when the wearable of --mock-kit-loose slips: give --mock-kit-loose I too"
    if args.mock_kit_misalignment and not (args.mock_kit and 0.0 < args.mock_kit_misalignment < 0.5):
        return ("--mock-kit-misalignment is the largest cross-axis entry of each simulated sensor's K, between 0 "
                "and 0.5 (e.g. 0.01), with --mock-kit")
    return None


def kit_scenario_problem(args: argparse.Namespace, scenarios: list[str]) -> str | None:
    """A kit's tray is turned by one clinician: the scripted one, or one hand:STYLE who follows the kit's prompts."""
    if not args.mock_kit:
        return None
    if set(scenarios) - {"normal"} and not (len(set(scenarios)) == 1 and scenarios[0].startswith("hand:")):
        return ("--mock-kit's tray is turned by one clinician: leave out --mock-scenario for the scripted one, or "
                "give one hand:STYLE (such as hand:careful) for one who follows the kit's prompts")
    if args.mock_kit_drop is not None and scenarios and scenarios[0].startswith("hand:"):
        return "--mock-kit-drop plays with the scripted tray clinician: leave out --mock-scenario hand:STYLE"
    return None


def tray_faults(args: argparse.Namespace) -> TrayFaults:
    """What goes wrong in the simulated kit's tray, from --mock-kit-loose, -loose-in, -out, -drop and -misalignment
    (numbered from 1 on the command line, from 0 in the tray); checked first by ``mock_problem``."""
    from calib.simulator.kit import TrayFaults  # the simulator's numerics load only with simulated wearables

    def index(number: int | None) -> int | None:
        return None if number is None else number - 1

    return TrayFaults(loose=index(args.mock_kit_loose), loose_in=args.mock_kit_loose_in, out=index(args.mock_kit_out),
                      drop=index(args.mock_kit_drop), misalignment=args.mock_kit_misalignment)
