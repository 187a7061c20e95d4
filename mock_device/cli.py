"""``gyrocal mock-device``: a simulated wearable on a simulated BlueZ, for any bleak program.

    gyrocal mock-device --ble [--model NAME] [--seed S] [--speed X] [--scenario NAME] [--replay FILE]

starts a private dbus-daemon, serves the wearable on it as ``org.bluez`` and prints one JSON line:
{"dbus_address": ..., "address": ..., "name": ..., "model": ..., "simulated_truth": {"k": [...], "b": [...]}}.
``--model`` picks the protocol it speaks: gyrocal (default), polar-pmd, metawear, thingy52 or movella-dot. ``--kit MODEL,MODEL,...``
serves one wearable of each model named, riding in one tray that one clinician turns (a kit to calibrate together).
It runs until SIGTERM or SIGINT, then stops its daemon. Run a bleak program with
DBUS_SYSTEM_BUS_ADDRESS set to ``dbus_address`` and it sees the wearable.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import signal
import sys
from typing import Any

from calib.cli.lazy_help import lazy_help
from calib.errors import GyrocalError
from wearable_protocol.models import MODELS

SCENARIO_NAMES = "{scenario names}"  # in a help text: filled in when the help is shown


def _scenario_names() -> str:
    from .scenarios import SCENARIOS  # calib's simulator: imported when the help is shown, not by every command

    return ", ".join(SCENARIOS)


def register(subparsers: Any) -> None:
    """Add the ``mock-device`` subcommand to gyrocal's CLI."""
    p = subparsers.add_parser(
        "mock-device",
        help="run a simulated wearable on a simulated BlueZ (private D-Bus) for bleak clients",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
        formatter_class=lazy_help(SCENARIO_NAMES, _scenario_names, argparse.RawDescriptionHelpFormatter),
    )
    p.add_argument("--ble", action="store_true", help="serve the wearable over the simulated BlueZ (required)")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulated sensor and clinician (default 0)")
    p.add_argument("--speed", type=float, default=1.0, help="device clock speed: 1 = real time, 20 = 20x (default 1)")
    p.add_argument("--scenario", default="normal", metavar="NAME",
                   help=f"what the simulated clinician does: {SCENARIO_NAMES} (default normal)")
    p.add_argument("--replay", metavar="FILE", default=None, help="replay a recorded CSV instead of simulating")
    p.add_argument("--fs", type=float, default=None, help="sample rate of the --replay file if it has no time column")
    p.add_argument("--model", default="gyrocal", choices=list(MODELS),
                   help="the protocol the wearable speaks (default gyrocal)")
    p.add_argument("--rate", type=float, default=None, help="initial sample rate in Hz (default: the model's, 104 for gyrocal)")
    p.add_argument("--count", type=int, default=1, help="number of wearables (seeds S, S+1, ...; default 1)")
    p.add_argument("--boot-count", type=int, default=1,
                   help="the power-up count the gyrocal wearable reports (default 1; each simulated power cycle adds one)")
    p.add_argument("--temperature", type=float, default=24.0, help="the IMU's temperature at power-up in degC (default 24)")
    p.add_argument("--kit", metavar="MODEL[,MODEL...]", default=None,
                   help="wearables of these models (one each, in this order; repeat a name for more) in one tray that one "
                        "clinician turns through the protocol: a kit to calibrate together")
    p.add_argument("--hide-optional-services", action="store_true",
                   help="hide Device Information and Battery, as some BlueZ versions do")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from .scenarios import SCENARIOS

    if args.scenario not in SCENARIOS:
        raise GyrocalError(f"unknown --scenario {args.scenario!r}: choose one of {', '.join(SCENARIOS)}")
    if not args.ble:
        raise GyrocalError("gyrocal mock-device serves the wearable over Bluetooth LE only: add --ble "
                           "(for an in-process wearable use `gyrocal serve --mock`)")
    if not (args.speed > 0):
        raise GyrocalError(f"--speed must be a positive number (1 = real time), got {args.speed}")
    if not 0 <= args.boot_count <= 0xFFFFFFFF:
        raise GyrocalError(f"--boot-count must be between 0 and 4294967295, got {args.boot_count}")
    if not -40.0 <= args.temperature <= 85.0:
        raise GyrocalError(f"--temperature must be within an IMU's operating range, -40 to 85 degC; got {args.temperature:g}")
    if not 1 <= args.count <= 64:
        raise GyrocalError(f"--count must be between 1 and 64, got {args.count}")
    if args.kit is not None:
        unknown = [m for m in args.kit.split(",") if m not in MODELS]
        if unknown or len(args.kit.split(",")) < 2:
            raise GyrocalError(f"--kit names the models of two or more wearables, comma-separated, from {', '.join(MODELS)}; "
                               f"got {args.kit!r}")
        if args.replay:
            raise GyrocalError("--kit simulates the tray's wearables: leave out --replay")
    if args.replay and args.scenario not in ("normal", "packet_loss"):
        raise GyrocalError(f"--scenario {args.scenario} scripts the simulated clinician; with --replay only "
                           "'normal' or 'packet_loss' (link faults) apply")
    return asyncio.run(_serve(args))


def _wearables(args: argparse.Namespace) -> list[Any]:
    from .power import PowerUpState
    from .scenarios import SCENARIOS
    from .sources import ReplaySource, ScriptedSource
    from .vendors import WEARABLES

    if args.kit is not None:
        from .kit import KitSource, Tray

        models = args.kit.split(",")
        tray = Tray(args.seed, len(models))
        return [WEARABLES[m](KitSource(tray, i), seed=args.seed + i, speed=args.speed,
                             power_up=PowerUpState(args.boot_count, args.temperature)) for i, m in enumerate(models)]
    model = MODELS[args.model]
    out = []
    for i in range(args.count):
        seed = args.seed + i
        if args.replay:
            source: Any = ReplaySource(args.replay, fs=args.fs)
            faults = SCENARIOS[args.scenario].faults
        else:
            source = ScriptedSource(seed=seed, scenario=args.scenario)
            faults = None
        rate = args.rate
        if rate is not None and not args.replay and not model.offers_rate(rate):
            raise GyrocalError(f"--rate {rate:g} is not offered by a {model.label}: choose {model.rates_text()}")
        out.append(WEARABLES[args.model](source, seed=seed, speed=args.speed, faults=faults, rate_hz=rate,
                                         power_up=PowerUpState(args.boot_count, args.temperature)))
    return out


async def _serve(args: argparse.Namespace) -> int:
    import wearable_protocol as wp

    from .bluez import PrivateBus, SimulatedBlueZ

    wearables = _wearables(args)
    bus = PrivateBus()
    address = bus.start()
    bluez = SimulatedBlueZ(
        wearables, hide_services=(wp.DEVICE_INFORMATION_SERVICE, wp.BATTERY_SERVICE) if args.hide_optional_services else (),
        seed=args.seed,
    )
    try:
        await bluez.start(address)
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, stop.set)
        devices = [{"address": w.address, "name": w.name, "model": w.model.key, "simulated_truth": w.truth} for w in wearables]
        line = {"dbus_address": address, **devices[0]}
        if len(devices) > 1:
            line["devices"] = devices
        print(json.dumps(line), flush=True)
        await stop.wait()
    finally:
        for w in wearables:
            await w.aclose()
        await bluez.stop()
        bus.stop()
    print("gyrocal: mock device stopped", file=sys.stderr)
    return 0
