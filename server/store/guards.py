"""The database's own refusal to change history: triggers on the append-only tables, and on PostgreSQL a
service role that may only read and append them.

SQLite: BEFORE UPDATE / DELETE triggers, and a BEFORE INSERT trigger that refuses a row whose id (or
session) is taken, so ``INSERT OR REPLACE`` cannot delete-and-rewrite a row (REPLACE's implicit delete
fires no delete trigger unless recursive triggers are on; gyrocal turns them on too).
PostgreSQL: row-level BEFORE UPDATE OR DELETE and statement-level BEFORE TRUNCATE triggers; the service
connects as a role that owns nothing and holds only SELECT and INSERT on these tables, so it cannot
drop or disable the triggers either (``gyrocal store setup``).
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import text

from .tables import APPEND_ONLY_TABLES

# the columns besides id that identify a row of each append-only table (unique)
_UNIQUE = {"calibrations": ("session_id", "chain_seq"), "recordings": ("session_id", "chain_seq"), "audit_log": ("chain_seq",)}


def _sqlite_guards() -> list[str]:
    out = []
    for t in APPEND_ONLY_TABLES:
        for op in ("UPDATE", "DELETE"):
            out.append(f"CREATE TRIGGER IF NOT EXISTS {t}_no_{op.lower()} BEFORE {op} ON {t} "
                       f"BEGIN SELECT RAISE(ABORT, '{t} is append-only'); END")
        taken = " OR ".join(f"EXISTS (SELECT 1 FROM {t} WHERE {c} = NEW.{c})" for c in ("id", *_UNIQUE[t]))
        out.append(f"CREATE TRIGGER IF NOT EXISTS {t}_no_replace BEFORE INSERT ON {t} WHEN {taken} "
                   f"BEGIN SELECT RAISE(ABORT, '{t} is append-only: that row exists and cannot be replaced'); END")
    return out


def _sqlite_drop() -> list[str]:
    return [f"DROP TRIGGER IF EXISTS {t}_no_{op}" for t in APPEND_ONLY_TABLES for op in ("update", "delete", "replace")]


_PG_FUNCTION = (
    "CREATE OR REPLACE FUNCTION gyrocal_append_only() RETURNS trigger AS $$ "
    "BEGIN RAISE EXCEPTION '% is append-only', TG_TABLE_NAME; END; $$ LANGUAGE plpgsql"
)


def _pg_guards() -> list[str]:
    out = [_PG_FUNCTION]
    for t in APPEND_ONLY_TABLES:
        out.append(f"CREATE TRIGGER {t}_append_only BEFORE UPDATE OR DELETE ON {t} "
                   "FOR EACH ROW EXECUTE FUNCTION gyrocal_append_only()")
        out.append(f"CREATE TRIGGER {t}_no_truncate BEFORE TRUNCATE ON {t} "
                   "FOR EACH STATEMENT EXECUTE FUNCTION gyrocal_append_only()")
    return out


def _pg_drop() -> list[str]:
    return [f"DROP TRIGGER IF EXISTS {t}_{name} ON {t}" for t in APPEND_ONLY_TABLES for name in ("append_only", "no_truncate")]


def install(conn: Any) -> None:
    """Create the guards (after the tables)."""
    dialect = conn.dialect.name
    stmts = _pg_guards() if dialect == "postgresql" else _sqlite_guards() if dialect == "sqlite" else []
    for stmt in stmts:
        conn.execute(text(stmt))


def remove(conn: Any) -> None:
    """Drop the guards (a schema migration that must rewrite history columns puts them back after)."""
    dialect = conn.dialect.name
    stmts = _pg_drop() if dialect == "postgresql" else _sqlite_drop() if dialect == "sqlite" else []
    for stmt in stmts:
        conn.execute(text(stmt))


# -- PostgreSQL: the service's role ------------------------------------------------------------------
APPEND_ONLY_GRANTS = "SELECT, INSERT"
READ_WRITE_TABLES = ("devices", "operators", "auth_tokens", "sessions", "kits", "chain_heads")
SPOOL_TABLES = ("session_samples", "gateways", "device_sightings", "device_leases")  # rows come and go


def grant_service_role(conn: Any, role: str) -> None:
    """Give a (non-owner) role what the service needs and nothing more: read and append the history,
    read and write the working tables, never truncate, update or delete history."""
    q = conn.dialect.identifier_preparer.quote
    r = q(role)
    db = conn.execute(text("SELECT current_database()")).scalar_one()
    conn.execute(text(f"GRANT CONNECT ON DATABASE {q(db)} TO {r}"))
    conn.execute(text(f"GRANT USAGE ON SCHEMA public TO {r}"))
    every = ("schema_info", "alembic_version", *APPEND_ONLY_TABLES, *READ_WRITE_TABLES, *SPOOL_TABLES)
    conn.execute(text(f"REVOKE ALL ON {', '.join(every)} FROM {r}"))
    conn.execute(text(f"GRANT SELECT ON schema_info, alembic_version TO {r}"))
    conn.execute(text(f"GRANT {APPEND_ONLY_GRANTS} ON {', '.join(APPEND_ONLY_TABLES)} TO {r}"))
    conn.execute(text(f"GRANT SELECT, INSERT, UPDATE ON {', '.join(READ_WRITE_TABLES)} TO {r}"))
    conn.execute(text(f"GRANT SELECT, INSERT, UPDATE, DELETE ON {', '.join(SPOOL_TABLES)} TO {r}"))
    conn.execute(text(f"GRANT USAGE, SELECT ON ALL SEQUENCES IN SCHEMA public TO {r}"))


def service_roles(conn: Any) -> list[str]:
    """The service roles `gyrocal store setup` made on this PostgreSQL database (those that may add sessions, other
    than the connected owner), quoted for SQL: an upgrade grants them its new tables so that they keep working."""
    q = conn.dialect.identifier_preparer.quote
    return [q(role) for role in conn.execute(text(
        "SELECT DISTINCT grantee FROM information_schema.role_table_grants WHERE table_schema = 'public' "
        "AND table_name = 'sessions' AND privilege_type = 'INSERT' AND grantee <> current_user"
    )).scalars()]


def role_may_rewrite_history(conn: Any) -> bool:
    """Whether the connected PostgreSQL role could get round the guards (superuser, or owner of the tables)."""
    row = conn.execute(text(
        "SELECT r.rolsuper OR EXISTS (SELECT 1 FROM pg_tables t WHERE t.schemaname = 'public' "
        "AND t.tablename = ANY(:tables) AND t.tableowner = current_user) FROM pg_roles r WHERE r.rolname = current_user"
    ), {"tables": list(APPEND_ONLY_TABLES)}).scalar_one()
    return bool(row)
