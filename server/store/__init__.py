"""The per-device store (SQLAlchemy 2): SQLite by default, PostgreSQL by URL.

tables (the schema) · engine (connections, SQLite write locking) · guards (append-only triggers, the
PostgreSQL service role) · chain (hash chains over the history) · schema (creation and migrations) · records
(what the store hands out) · base (transactions, integrity, audit log) · operators · sessions (sessions, spool,
recordings) · calibrations (the history) · fleet (gateways, sightings, leases) · repository (the Store: all of them,
and the devices).
"""

from .chain import BrokenLink, ChainReport
from .errors import DecisionConflict, NotAcceptable, NotFound, StoreError, StoreFull, store_trouble
from .fleet import Lease
from .records import CalibrationRecord, SessionEnd, StoredDevice, StoredSession, StoredVerification, StoredWatch, sha256_hex
from .repository import Store
from .schema import SCHEMA_VERSION
from .spool import BINARY_SPOOL
from .tables import utcnow

__all__ = [
    "BINARY_SPOOL",
    "SCHEMA_VERSION",
    "BrokenLink",
    "CalibrationRecord",
    "ChainReport",
    "DecisionConflict",
    "Lease",
    "NotAcceptable",
    "NotFound",
    "SessionEnd",
    "Store",
    "StoreError",
    "StoreFull",
    "StoredDevice",
    "StoredSession",
    "StoredVerification",
    "StoredWatch",
    "sha256_hex",
    "store_trouble",
    "utcnow",
]
