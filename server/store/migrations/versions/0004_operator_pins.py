"""An operator's short PIN for signing in on the tablets the service trusts (operators.pin_hash).

Revision ID: 0004
Revises: 0003
"""

from __future__ import annotations

from alembic import op
from sqlalchemy import text

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None


def upgrade() -> None:
    """v3 -> v4: operators' PINs (operators is not append-only: no guard changes)."""
    conn = op.get_bind()
    conn.execute(text("ALTER TABLE operators ADD COLUMN pin_hash VARCHAR(512)"))
