"""The per-device store: every read and write of the service, each one transaction.

Calibrations, archived recordings and the audit log are append-only (the database refuses UPDATE,
DELETE, REPLACE and TRUNCATE on them) and hash-chained (tampering shows in ``verify()``); the current
calibration of a device is its latest accepted one. Sessions (live or uploaded) are kept whatever their
outcome. Accepting or discarding a session is a compare-and-set on its undecided state: of any number of
concurrent decisions exactly one wins, the others get DecisionConflict.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from .calibrations import CalibrationStore
from .fleet import FleetStore
from .kits import KitStore
from .operators import OperatorStore
from .records import StoredDevice, device_dict
from .tables import Device, utcnow


class Store(OperatorStore, CalibrationStore, FleetStore, KitStore):
    """All persistent state of the service. Thread-safe; every method is one transaction."""

    # -- devices --------------------------------------------------------------------------------
    def upsert_device(self, device_id: str, **info: Any) -> None:
        """Record a device (or what is newly known about it) and when it was last seen."""
        now = utcnow()
        cols = {"name", "address", "transport", "sensor_model", "firmware", "serial"}
        with self._tx() as s:
            row = self._device_row(s, device_id, now)
            for key, value in info.items():
                if key in cols and value is not None:
                    setattr(row, key, str(value))
            if info.get("power_up") is not None:
                row.power_up = {**info["power_up"], "read_at": now.isoformat()}
            row.last_seen = now

    def record_held(self, device_id: str, calibration_id: int | None, operator: str | None = None,
                    written: bool = False) -> None:
        """What the wearable just reported holding (None: nothing). ``written``: it was read back after a write-back by
        ``operator``, which the audit log keeps (the device row keeps only the latest report)."""
        with self._tx(*(("audit_log",) if written else ())) as s:
            now = utcnow()
            row = self._device_row(s, device_id, now)
            row.held_calibration_id, row.held_reported_at, row.last_seen = calibration_id, now, now
            if written:
                self._audit(s, operator, "device.write_back", device_id, None, {"calibration_id": calibration_id})

    def _device_row(self, s: Session, device_id: str, now: datetime) -> Device:
        """The device's row, created first when missing; atomically, so services meeting a new device at once all
        get the one row (a read, then an insert, would let the second insert fail)."""
        s.execute(self._insert(Device).values(id=device_id, first_seen=now, last_seen=now)
                  .on_conflict_do_nothing(index_elements=[Device.id]))
        return s.get_one(Device, device_id)

    def devices(self) -> list[StoredDevice]:
        with self._read() as s:
            return [device_dict(r) for r in s.execute(select(Device).order_by(Device.id)).scalars()]

    def device(self, device_id: str) -> StoredDevice | None:
        with self._read() as s:
            row = s.get(Device, device_id)
            return None if row is None else device_dict(row)
