"""`gyrocal operator`: the operators who may write to the service, their hashed secrets and PINs."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from .cli import EXIT_OK, ServiceError, open_store
from .config import DB_URL_HELP


def register_operator(sub: Any) -> None:
    """Add `gyrocal operator add|list|remove|reset`."""
    p = sub.add_parser("operator", help="manage the operators who may write to the service (hashed secrets)")
    p.add_argument("--db", default=None, metavar="URL", help=DB_URL_HELP)
    # --db is accepted after the action too (`gyrocal operator add NAME --db URL`, as the docs write it); SUPPRESS
    # keeps an action without it from overwriting a --db given before the action
    db_after = argparse.ArgumentParser(add_help=False)
    db_after.add_argument("--db", default=argparse.SUPPRESS, metavar="URL", help=DB_URL_HELP)
    osub = p.add_subparsers(dest="operator_command", metavar="ACTION", required=True)

    def action(name: str, help: str) -> Any:
        return osub.add_parser(name, help=help, parents=[db_after])

    a = action("add", "add an operator; prints the secret once")
    a.add_argument("name")
    a.add_argument("--secret-stdin", action="store_true", help="read the secret from standard input instead of generating one")
    a.set_defaults(func=cmd_operator_add)
    r = action("reset", "give an operator a new secret (signs them out everywhere)")
    r.add_argument("name")
    r.add_argument("--secret-stdin", action="store_true", help="read the secret from standard input instead of generating one")
    r.set_defaults(func=cmd_operator_reset)
    d = action("remove", "disable an operator (kept in the audit trail)")
    d.add_argument("name")
    d.set_defaults(func=cmd_operator_remove)
    pn = action("pin", "give an operator a PIN of 4-8 digits for the tablets the service trusts (or --remove it)")
    pn.add_argument("name")
    pn.add_argument("--pin-stdin", action="store_true", help="read the PIN from standard input (else it is asked for)")
    pn.add_argument("--remove", action="store_true", help="take the operator's PIN away")
    pn.set_defaults(func=cmd_operator_pin)
    ls = action("list", "list operators")
    ls.set_defaults(func=cmd_operator_list)


def _read_secret() -> str:
    secret = sys.stdin.readline().rstrip("\r\n")
    if not secret:
        raise ServiceError("no secret on standard input")
    return secret


def _auth(args: argparse.Namespace) -> Any:
    from .auth import Authenticator

    return Authenticator(open_store(args.db))


def cmd_operator_add(args: argparse.Namespace) -> int:
    from .auth import AuthError
    from .store import StoreError

    auth = _auth(args)
    try:
        secret = auth.add_operator(args.name, _read_secret() if args.secret_stdin else None)
    except (AuthError, StoreError) as exc:
        raise ServiceError(str(exc)) from None
    if args.secret_stdin:
        print(f"operator {args.name} added")
    else:
        print(f"operator {args.name} added; their secret (shown once, store it safely):")
        print(secret)
    return EXIT_OK


def cmd_operator_reset(args: argparse.Namespace) -> int:
    from .auth import AuthError
    from .store import StoreError

    auth = _auth(args)
    try:
        secret = auth.reset_operator(args.name, _read_secret() if args.secret_stdin else None)
    except (AuthError, StoreError) as exc:
        raise ServiceError(str(exc)) from None
    print(f"operator {args.name} has a new secret" + ("" if args.secret_stdin else " (shown once):"))
    if not args.secret_stdin:
        print(secret)
    return EXIT_OK


def cmd_operator_pin(args: argparse.Namespace) -> int:
    import getpass

    from .auth import AuthError
    from .store import StoreError

    pin = None
    if not args.remove:
        pin = sys.stdin.readline().strip() if args.pin_stdin else getpass.getpass(f"PIN for {args.name} (4-8 digits): ")
    try:
        _auth(args).set_pin(args.name, pin)
    except (AuthError, StoreError) as exc:
        raise ServiceError(str(exc)) from None
    print(f"operator {args.name} " + ("has no PIN now" if args.remove else "has a new PIN"))
    return EXIT_OK


def cmd_operator_remove(args: argparse.Namespace) -> int:
    from .store import StoreError

    try:
        open_store(args.db).disable_operator(args.name)
    except StoreError as exc:
        raise ServiceError(str(exc)) from None
    print(f"operator {args.name} removed")
    return EXIT_OK


def cmd_operator_list(args: argparse.Namespace) -> int:
    ops = open_store(args.db).operators()
    if not ops:
        print("no operators yet: add one with `gyrocal operator add NAME`")
    for op in ops:
        print(f"{op['name']:<24} {'active' if op['active'] else 'removed':<8} since {op['created_at'][:19]}")
    return EXIT_OK
