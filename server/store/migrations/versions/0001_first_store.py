"""The first store (gyrocal's schema version 1): devices, operators, sessions, recordings, calibrations, the
audit log. Stores this old are only ever stamped with this revision and upgraded from it; an empty database
gets the newest schema at once.

Revision ID: 0001
"""

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None


def upgrade() -> None:
    """Nothing: a store at this revision was created by gyrocal 0.x's own schema steps."""
