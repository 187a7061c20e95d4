"""`gyrocal serve` and `gyrocal operator`: the service's commands (plugged into calib's CLI)."""

from __future__ import annotations

import argparse
import gc
import logging
import math
import re
import signal
import sys
from typing import TYPE_CHECKING, Any

from calib.errors import GyrocalError

from .config import DEFAULT_HEADER_TIMEOUT_S, DEFAULT_MAX_CONNECTIONS
from .mock_cli import add_mock_options, kit_scenario_problem, mock_problem, tray_faults

if TYPE_CHECKING:
    from .config import GatewaySettings

EXIT_OK = 0
EXIT_USAGE = 2


class ServiceError(GyrocalError):
    """The service cannot start as asked; the message says why."""


def register(sub: Any) -> None:
    """Add `gyrocal serve`."""
    from .config import DEFAULT_LEASE_S, DEFAULT_MAX_AGE_DAYS

    p = sub.add_parser(
        "serve",
        help="run the calibration service (REST API, live guided sessions, per-device store)",
        description="Run the calibration service. Reads are open to whoever can reach it (it binds to "
        "127.0.0.1 by default); writes need an operator's token (gyrocal operator add NAME, or GYROCAL_API_TOKEN).",
    )
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this computer only)")
    p.add_argument("--port", type=int, default=8000, help="TCP port (default 8000; 0 picks a free one)")
    p.add_argument("--db", default=None, metavar="URL",
                   help="SQLAlchemy URL of the store: sqlite:///path or postgresql://user@host/db "
                   "(default: GYROCAL_DB, else gyrocal.sqlite3 in the user's data directory)")
    add_mock_options(p)
    p.add_argument(
        "--ble",
        action="store_true",
        help="use Bluetooth LE wearables through bleak (BlueZ, or the simulated one via DBUS_SYSTEM_BUS_ADDRESS)",
    )
    p.add_argument("--ble-adapter", default="hci0", metavar="HCI[,HCI...]",
                   help="Bluetooth adapters to connect through, e.g. hci0,hci1: each wearable goes to the one with the most "
                        "free connection slots (default hci0)")
    p.add_argument("--ble-slots", type=int, default=5, metavar="N",
                   help="connections one adapter holds at once (BlueZ adapters: 5 on CSR chips, 7 on Broadcom; default 5)")
    p.add_argument("--ble-time-scale", type=float, default=1.0, metavar="X",
                   help="the wearables' clocks run X times real time: 1 for real hardware (default); a simulated wearable "
                        "replayed faster (gyrocal mock-device --speed X) needs its speed, or its time stamps are refused "
                        "as running ahead of real time")
    p.add_argument("--auth-reads", action="store_true", help="require a token for reads too (default: only writes need one)")
    p.add_argument(
        "--allowed-host",
        action="append",
        default=[],
        metavar="NAME",
        help="a name the service answers to besides localhost and the --host address (repeatable; '*' for any): "
        "requests for other Host names get 400, so a web page elsewhere cannot rebind its name to this service",
    )
    p.add_argument(
        "--open-reads",
        action="store_true",
        help="with a --host other computers reach: let them read devices, sessions and calibrations without a "
        "token over plain HTTP (default: refuse to start so, unless --auth-reads)",
    )
    p.add_argument(
        "--worker-memory-mb",
        type=int,
        default=3072,
        metavar="MB",
        help="memory each worker process (estimator, model check) may take; beyond it the request gets 413 (default 3072)",
    )
    p.add_argument(
        "--allow-db-owner",
        action="store_true",
        help="PostgreSQL: run even when connected as the tables' owner or a superuser, who could drop the "
        "append-only guards (default: refuse; create a service role with `gyrocal store setup --service-role`)",
    )
    p.add_argument("--method", default="closure", help="estimator of live sessions (default closure)")
    p.add_argument(
        "--heading-prior-deg",
        type=float,
        default=None,
        metavar="DEG",
        help="how far (1 sigma, deg) a device's heading may be off after each turn at this site, where it is known "
        "(closure; uploads may state their own); default: learned from each recording's turns about horizontal axes",
    )
    p.add_argument(
        "--max-attempts",
        type=int,
        default=3,
        metavar="N",
        help="tries per turn before a session fails (default 3; 1: any fault ends the session with its reason)",
    )
    p.add_argument(
        "--calibration-max-age-days",
        type=float,
        default=DEFAULT_MAX_AGE_DAYS,
        metavar="DAYS",
        help=f"a device whose calibration is older is due, and applying that calibration warns (default {DEFAULT_MAX_AGE_DAYS:g})",
    )
    p.add_argument(
        "--calibration-max-temperature-change-c",
        type=float,
        default=3.0,
        metavar="DEGC",
        help="applying a calibration to a recording this much warmer or colder than the calibration warns (default 3)",
    )
    p.add_argument(
        "--pin-from",
        action="append",
        default=[],
        metavar="NETWORK",
        help="also accept operators' PINs from this network (e.g. 10.1.2.0/24, the ward's tablets); this computer always may",
    )
    p.add_argument(
        "--demo-operator",
        default=None,
        metavar="NAME",
        help="create operator NAME (or give it a new secret) and print the secret: for trying the service",
    )
    p.add_argument("--gateway", default=None, metavar="NAME",
                   help="run as the gateway NAME of a fleet sharing one store (one per room; see docs/deployment.md)")
    p.add_argument("--gateway-url", default=None, metavar="URL",
                   help="where clinicians reach this gateway from other rooms (default http://HOST:PORT)")
    p.add_argument("--lease-s", type=float, default=DEFAULT_LEASE_S, metavar="S",
                   help=f"a gateway's hold on a wearable lasts S seconds past its last heartbeat (default {DEFAULT_LEASE_S:g})")
    p.add_argument("--header-timeout-s", type=float, default=DEFAULT_HEADER_TIMEOUT_S, metavar="S",
                   help=f"close a connection that has not sent a whole request's headers within S seconds (default "
                   f"{DEFAULT_HEADER_TIMEOUT_S:g}; half-open connections are how a service is starved of file descriptors)")
    p.add_argument("--max-connections", type=int, default=DEFAULT_MAX_CONNECTIONS, metavar="N",
                   help=f"at most N open connections (default {DEFAULT_MAX_CONNECTIONS}, and always below the file limit): "
                   "beyond it the longest-waiting connection without a request is closed")
    p.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])
    p.set_defaults(func=cmd_serve)


# -- operator ------------------------------------------------------------------------------------
def open_store(url: str | None) -> Any:
    from .config import default_db_url
    from .store import Store, StoreError

    try:
        return Store(url or default_db_url())
    except StoreError as exc:
        raise ServiceError(str(exc)) from None


def require_active_operator(store: Any, name: str) -> None:
    """ServiceError unless ``name`` is an active operator of ``store`` (who the CLI records as having done it)."""
    if not any(o["name"] == name and o["active"] for o in store.operators()):
        raise ServiceError(f"no active operator {name!r} in {store.display_url}; `gyrocal operator list` names them")


# -- serve ---------------------------------------------------------------------------------------
def pin_networks(given: list[str]) -> list[str]:
    """The --pin-from networks, checked."""
    import ipaddress

    try:
        return [str(ipaddress.ip_network(n, strict=False)) for n in given]
    except ValueError as exc:
        raise ServiceError(f"--pin-from: {exc}; give a network such as 10.1.2.0/24 or one address") from None


def build_service(args: argparse.Namespace) -> Any:
    """Settings, store and devices from the command line (no event loop needed)."""
    from calib.estimators.registry import method_names

    from .config import CalibrationLimits, Settings, default_db_url
    from .devices import DeviceManager, SimulatorsUnavailable, load_simulators
    from .service import Service

    if (problem := mock_problem(args)) is not None:
        raise ServiceError(problem)
    if not (0.5 <= args.header_timeout_s <= 600):
        raise ServiceError("--header-timeout-s must be between 0.5 and 600 seconds")
    if not (16 <= args.max_connections <= 1_000_000):
        raise ServiceError("--max-connections must be between 16 and 1000000")
    simulators = None
    if args.mock:
        try:
            simulators = load_simulators()
        except SimulatorsUnavailable as exc:
            raise ServiceError(f"--mock needs the simulated wearables, and {exc}") from None
    if simulators is not None and args.mock_model not in simulators.models:
        raise ServiceError(f"unknown --mock-model {args.mock_model!r}: choose one of {', '.join(simulators.models)}")
    if simulators is not None and args.mock_rate is not None:
        offered = simulators.rates_instead(args.mock_model, args.mock_rate)
        if offered is not None:
            raise ServiceError(f"--mock-rate must be {offered} for a {args.mock_model} wearable")
    if args.method not in method_names():
        raise ServiceError(f"--method must be one of {', '.join(method_names())}")
    if args.heading_prior_deg is not None:
        from calib.errors import GyrocalError
        from calib.pipeline import method_options

        try:
            method_options(args.method, args.heading_prior_deg)
        except GyrocalError as exc:
            raise ServiceError(f"--heading-prior-deg: {exc}") from None
    loopback = args.host in ("127.0.0.1", "::1", "localhost")
    if not loopback and not args.auth_reads and not args.open_reads:
        raise ServiceError(
            f"--host {args.host} lets other computers reach the service, and reads (devices, sessions, calibrations) are "
            "open over plain HTTP: add --auth-reads so reads need a token too, or --open-reads to allow it knowingly"
        )
    hosts = ("localhost", "127.0.0.1", "::1", *([] if args.host in ("0.0.0.0", "::", "") else [args.host]), *args.allowed_host)
    if not 256 <= args.worker_memory_mb <= 1_048_576:
        raise ServiceError("--worker-memory-mb must be between 256 and 1048576")
    if not args.calibration_max_age_days > 0:
        raise ServiceError("--calibration-max-age-days must be a positive number of days")
    if not args.calibration_max_temperature_change_c > 0:
        raise ServiceError("--calibration-max-temperature-change-c must be a positive number of degrees Celsius")
    if not 1 <= args.max_attempts <= 5:
        raise ServiceError("--max-attempts must be between 1 and 5")
    scenarios = [s.strip() for s in args.mock_scenario.split(",") if s.strip()]
    unknown = [s for s in scenarios if simulators is not None and s not in simulators.scenarios]
    if simulators is not None and unknown:
        raise ServiceError(f"unknown --mock-scenario {', '.join(unknown)}: choose from {', '.join(simulators.scenarios)}")
    if (problem := kit_scenario_problem(args, scenarios)) is not None:
        raise ServiceError(problem)
    settings = Settings(
        db_url=args.db or default_db_url(),
        host=args.host,
        port=args.port,
        auth_reads=args.auth_reads,
        method=args.method,
        heading_prior_deg=args.heading_prior_deg,
        max_turn_attempts=args.max_attempts,
        worker_memory_mb=args.worker_memory_mb,
        allowed_hosts=tuple(dict.fromkeys(h.lower() for h in hosts)),
        pin_from=(*Settings.pin_from, *pin_networks(args.pin_from)),
        limits=CalibrationLimits(args.calibration_max_age_days, args.calibration_max_temperature_change_c),
        gateway=gateway_settings(args),
    )
    from .store import Store, StoreError

    try:
        store = Store(settings.db_url)
    except StoreError as exc:
        raise ServiceError(str(exc)) from None
    if not args.allow_db_owner and store.role_may_rewrite_history():
        store.close()
        raise ServiceError(
            f"the service connects to {store.display_url} as the tables' owner (or a superuser), who could drop the guards "
            "that keep the history append-only. Create a service role once with `gyrocal store setup --db <this URL> "
            "--service-role gyrocal_service` and start the service with the URL it prints (or pass --allow-db-owner to "
            "run like this anyway)"
        )
    adapters = [a.strip() for a in str(args.ble_adapter).split(",")]
    if not all(re.fullmatch(r"hci\d{1,2}", a) for a in adapters) or len(set(adapters)) != len(adapters):
        raise ServiceError(f"--ble-adapter {args.ble_adapter!r}: name each adapter once, as BlueZ does (hci0, or hci0,hci1)")
    if not 1 <= args.ble_slots <= 20:
        raise ServiceError(f"--ble-slots {args.ble_slots}: an adapter holds between 1 and 20 connections (BlueZ adapters 5-7)")
    if not (math.isfinite(args.ble_time_scale) and 0 < args.ble_time_scale <= 1000):
        raise ServiceError(f"--ble-time-scale {args.ble_time_scale:g}: give how many times real time the wearables' "
                           "clocks run, above 0 and at most 1000 (1 for real hardware)")
    devices = DeviceManager(ble=args.ble, ble_adapters=adapters, ble_slots=args.ble_slots, ble_time_scale=args.ble_time_scale)
    if simulators is not None:
        devices.add_mocks(simulators, args.mock, speed=args.mock_speed, seed=args.mock_seed, scenarios=scenarios, rate_hz=args.mock_rate,
                          first=args.mock_first, model=args.mock_model, kit=args.mock_kit,
                          faults=tray_faults(args) if args.mock_kit else None)
    return Service(settings, store=store, devices=devices)


def gateway_settings(args: argparse.Namespace) -> GatewaySettings | None:
    """--gateway and its options, checked; None for a service on its own."""
    from .config import DEFAULT_HEARTBEAT_S, GatewaySettings

    if args.gateway is None:
        if args.gateway_url is not None:
            raise ServiceError("--gateway-url needs --gateway NAME: the URL is where other rooms' pages find this gateway")
        return None
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}", args.gateway):
        raise ServiceError(f"--gateway {args.gateway!r}: use letters, digits, '.', '_' or '-' (up to 64), e.g. birth-room-3")
    if not 5.0 <= args.lease_s <= 3600.0:
        raise ServiceError(f"--lease-s {args.lease_s:g}: between 5 and 3600 seconds (a lease must outlast a few heartbeats)")
    url = args.gateway_url or f"http://{args.host}:{args.port}"
    if not re.fullmatch(r"https?://[^\s/]+(/\S*)?", url):
        raise ServiceError(f"--gateway-url {url!r}: give the http(s):// address clinicians use to reach this gateway")
    return GatewaySettings(args.gateway, url.rstrip("/"), lease_s=args.lease_s, heartbeat_s=min(DEFAULT_HEARTBEAT_S, args.lease_s / 4))


def cmd_serve(args: argparse.Namespace) -> int:
    import socket

    import uvicorn

    from . import log_repeats
    from .http_guard import ACCEPT_BURST, connection_bound, guarded_protocol, raise_file_limit
    from .main import create_app

    logging.basicConfig(level=args.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    svc = build_service(args)
    app = create_app(service=svc)
    try:
        sock = socket.socket(socket.AF_INET6 if ":" in args.host else socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((args.host, args.port))
        sock.listen(ACCEPT_BURST)  # from now on a connection waits for the app instead of being refused: the URL printed is true
    except OSError as exc:
        raise ServiceError(f"cannot listen on {args.host}:{args.port} ({exc.strerror or exc}); choose another --port") from None
    port = sock.getsockname()[1]
    host = f"[{args.host}]" if ":" in args.host else args.host
    shown = "127.0.0.1" if args.host in ("0.0.0.0", "") else host
    svc.devices.service_url = f"http://{shown}:{port}"
    mocks = ", ".join(d for d in svc.devices.devices if d.startswith("mock-"))
    print(
        f"gyrocal calibration service: open the wizard at http://{shown}:{port}/ "
        f"(API: http://{shown}:{port}/docs; store: {svc.store.display_url})",
        flush=True,
    )
    if mocks:
        print(f"simulated wearables: {mocks} (speed {args.mock_speed:g}x)", flush=True)
    if args.demo_operator:
        from .auth import Authenticator, AuthError

        auth = Authenticator(svc.store)
        try:
            if any(o["name"] == args.demo_operator and o["active"] for o in svc.store.operators()):
                secret = auth.reset_operator(args.demo_operator)
            else:
                secret = auth.add_operator(args.demo_operator)
        except AuthError as exc:
            raise ServiceError(str(exc)) from None
        print(f"sign in as operator {args.demo_operator!r} with the secret {secret}", flush=True)
    elif not svc.settings.api_token and not svc.store.operators():
        print("no operators yet: add one with `gyrocal operator add NAME` (or set GYROCAL_API_TOKEN) to start calibrations", flush=True)
    if args.host not in ("127.0.0.1", "::1", "localhost"):
        print(f"warning: listening on {args.host}: other computers can reach the service", file=sys.stderr, flush=True)
    file_limit = raise_file_limit()
    max_connections = connection_bound(args.max_connections, file_limit)
    if max_connections < args.max_connections:
        print(f"warning: at most {max_connections} connections, not {args.max_connections}: this process may open "
              f"{file_limit} files (ulimit -n; LimitNOFILE= in a systemd unit raises it)", file=sys.stderr, flush=True)
    config = uvicorn.Config(app, log_level=args.log_level, access_log=args.log_level == "debug", timeout_graceful_shutdown=5,
                            http=guarded_protocol(args.header_timeout_s, max_connections), backlog=ACCEPT_BURST)
    log_repeats.install()  # after uvicorn has set up its loggers' handlers
    server = uvicorn.Server(config)
    # uvicorn stops gracefully on SIGTERM, then raises the signal again for the handler it found: this one makes a
    # stop asked for (systemd, docker, make run's terminal) an ordinary end, exit 0, as Ctrl-C already is
    signal.signal(signal.SIGTERM, lambda _sig, _frame: None)
    # what is loaded by now lives as long as the process: the collector need not walk it again at every full
    # collection while sessions stream, nor at exit
    gc.freeze()
    try:
        server.run(sockets=[sock])
    except KeyboardInterrupt:
        pass
    return EXIT_OK
