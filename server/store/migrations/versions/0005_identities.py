"""Each calibration's sensor, power-up and temperature (calibrations.identity) and each device's last
reported power-up (devices.power_up).

Revision ID: 0005
Revises: 0004
"""

from __future__ import annotations

from alembic import op
from sqlalchemy import text

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    """v4 -> v5: identities (a new column is NULL on the existing rows: no row changes, their hashes stand)."""
    conn = op.get_bind()
    conn.execute(text("ALTER TABLE calibrations ADD COLUMN identity JSON"))
    conn.execute(text("ALTER TABLE devices ADD COLUMN power_up JSON"))
