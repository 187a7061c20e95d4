"""Kits: a kit session's wearables, and how they followed the tray once calibrated together, kept so that a kit is
shown and accepted after the service restarts. A service role the store was set up with gets the table too.

Revision ID: 0007
Revises: 0006
"""

from __future__ import annotations

from alembic import op
from sqlalchemy import text

from server.store.guards import service_roles
from server.store.tables import Base, KitRow

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None


def upgrade() -> None:
    conn = op.get_bind()
    Base.metadata.create_all(conn, tables=[KitRow.__table__])  # type: ignore[list-item]
    if conn.dialect.name == "postgresql":
        for role in service_roles(conn):
            conn.execute(text(f"GRANT SELECT, INSERT, UPDATE ON kits TO {role}"))
