"""What each wearable last reported holding (devices.held_calibration_id, held_reported_at).

Revision ID: 0003
Revises: 0002
"""

from __future__ import annotations

from alembic import op
from sqlalchemy import text

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    """v2 -> v3: the calibration each wearable holds (devices is not append-only: no guard changes)."""
    conn = op.get_bind()
    conn.execute(text("ALTER TABLE devices ADD COLUMN held_calibration_id INTEGER"))
    kind = "TIMESTAMP WITH TIME ZONE" if conn.dialect.name == "postgresql" else "DATETIME"
    conn.execute(text(f"ALTER TABLE devices ADD COLUMN held_reported_at {kind}"))
