"""`gyrocal store setup` and `gyrocal store verify`: create or upgrade the store, give the service its
database role, and check the history's hash chains (plugged into calib's CLI)."""

from __future__ import annotations

import argparse
import json
import re
import secrets
import sys
from typing import Any

from .cli import ServiceError
from .config import DB_URL_HELP

EXIT_OK = 0
EXIT_TAMPERED = 4  # `gyrocal store verify`: a hash chain is broken
ROLE_RE = re.compile(r"^[a-z_][a-z0-9_]{0,62}$")


def register(sub: Any) -> None:
    """Add `gyrocal store setup|verify`."""
    p = sub.add_parser("store", help="create or upgrade the store, give the service its database role, verify the history")
    ssub = p.add_subparsers(dest="store_command", metavar="ACTION", required=True)
    s = ssub.add_parser(
        "setup",
        help="create or upgrade the store's schema (as the tables' owner); on PostgreSQL also the service's role",
        description="Create the store's schema on an empty database, or upgrade an older one. On PostgreSQL, run it with "
        "the URL of the role that will own the tables and give --service-role: that role is created (or updated) with "
        "only what the service needs (read and append the history; never update, delete or truncate it), and the "
        "service is then started with its URL.",
    )
    s.add_argument("--db", required=True, metavar="URL", help="the store's URL, as the tables' owner")
    s.add_argument("--service-role", default=None, metavar="NAME",
                   help="PostgreSQL: the login role `gyrocal serve` connects as (created if missing)")
    s.add_argument("--password-stdin", action="store_true", help="read the service role's password from standard input "
                   "(default: generate one and print it once)")
    s.set_defaults(func=cmd_setup)
    v = ssub.add_parser("verify", help="check the hash chains over calibrations, recordings and the audit log",
                        description="Walk the hash chains over the store's history. Exit 0: intact. Exit 4: a link is "
                        "broken; the first broken one is printed (a row changed, removed or replaced after it was written).")
    v.add_argument("--db", default=None, metavar="URL", help=DB_URL_HELP)
    v.add_argument("--json", action="store_true", help="print the report as one JSON object")
    v.set_defaults(func=cmd_verify)


def _open(url: str) -> Any:
    from .store import Store, StoreError

    try:
        return Store(url)
    except StoreError as exc:
        raise ServiceError(str(exc)) from None


def cmd_setup(args: argparse.Namespace) -> int:
    store = _open(args.db)
    print(f"store at {store.display_url}: schema version {store.schema_version()}")
    if args.service_role is None:
        if store.dialect == "postgresql":
            print("no --service-role given: the service should not connect as the tables' owner (it could drop the "
                  "append-only guards); run again with --service-role NAME", file=sys.stderr)
        return EXIT_OK
    if store.dialect != "postgresql":
        raise ServiceError("--service-role is for PostgreSQL; a SQLite store is protected by its file's permissions")
    if not ROLE_RE.match(args.service_role):
        raise ServiceError("--service-role: 1-63 lower-case letters, digits or _, starting with a letter or _")
    if args.password_stdin:
        password = sys.stdin.readline().rstrip("\r\n")
        if len(password) < 12:
            raise ServiceError("the service role's password needs at least 12 characters")
    else:
        password = secrets.token_urlsafe(24)
    from sqlalchemy import text

    from .store.guards import grant_service_role

    with store.engine.begin() as conn:
        exists = conn.execute(text("SELECT 1 FROM pg_roles WHERE rolname = :r"), {"r": args.service_role}).first()
        verb = "ALTER" if exists else "CREATE"
        quoted = conn.dialect.identifier_preparer.quote(args.service_role)
        literal = "'" + password.replace("'", "''") + "'"
        conn.execute(text(f"{verb} ROLE {quoted} LOGIN NOSUPERUSER NOCREATEDB NOCREATEROLE PASSWORD {literal}"))
        grant_service_role(conn, args.service_role)
    url = store.engine.url.set(username=args.service_role, password=password, drivername="postgresql")
    print(f"role {args.service_role} {'updated' if exists else 'created'}: it may read and append the history, never change it")
    shown = url.render_as_string(hide_password=args.password_stdin)
    print(f"start the service with: gyrocal serve --db '{shown}'")
    return EXIT_OK


def cmd_verify(args: argparse.Namespace) -> int:
    from .config import default_db_url

    store = _open(args.db or default_db_url())
    report = store.verify()
    if args.json:
        print(json.dumps(report.to_dict()))
    else:
        counts = ", ".join(f"{n} {chain}" for chain, n in report.rows.items())
        if report.ok:
            print(f"the store's history is intact: {counts} rows verified")
        else:
            b = report.broken
            assert b is not None
            where = f"row {b.seq} of the {b.chain} chain" + (f" (id {b.row_id})" if b.row_id is not None else "")
            print(f"the store's history was tampered with: {where}: {b.problem}. Checked before it: {counts}", file=sys.stderr)
    return EXIT_OK if report.ok else EXIT_TAMPERED
