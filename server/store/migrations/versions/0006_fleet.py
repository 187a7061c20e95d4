"""The fleet: gateways (one service per room), the wearables each has seen, the lease that lets one gateway
at a time run a session on a wearable, and the gateway each session runs on. A service role the store was set up with gets these tables too.

Revision ID: 0006
Revises: 0005
"""

from __future__ import annotations

from alembic import op
from sqlalchemy import text

from server.store.guards import service_roles
from server.store.tables import Base, GatewayRow, LeaseRow, SightingRow

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None


def upgrade() -> None:
    conn = op.get_bind()
    Base.metadata.create_all(conn, tables=[GatewayRow.__table__, SightingRow.__table__, LeaseRow.__table__])  # type: ignore[list-item]
    conn.execute(text("ALTER TABLE sessions ADD COLUMN gateway VARCHAR(64)"))
    if conn.dialect.name == "postgresql":
        for role in service_roles(conn):
            conn.execute(text(f"GRANT SELECT, INSERT, UPDATE, DELETE ON gateways, device_sightings, device_leases TO {role}"))
            conn.execute(text(f"GRANT SELECT ON alembic_version TO {role}"))
