"""Kit sessions: which wearables' sessions make up a kit, and how they followed the tray once calibrated together."""

from __future__ import annotations

from typing import Any

from sqlalchemy import select

from .records import StoredKit, StoredSession, iso_utc, session_dict
from .sessions import SessionStore
from .tables import KitRow, SessionRow, utcnow


class KitStore(SessionStore):
    """The kits' part of the store. Each wearable's session is an ordinary session; the kit row groups them."""

    def create_kit(self, kit_id: str, operator: str | None, members: dict[str, str], gateway: str | None = None) -> None:
        """Record a kit session over ``members`` (device id -> its session id, each session created already)."""
        with self._tx("audit_log") as s:
            s.add(KitRow(id=kit_id, operator=operator, gateway=gateway, started_at=utcnow(),
                         members=[{"device_id": d, "session_id": sid} for d, sid in members.items()]))
            self._audit(s, operator, "kit.start", None, kit_id, {"devices": list(members), "sessions": members})

    def record_kit_outcome(self, kit_id: str, consistency: dict[str, Any] | None, departed: list[str],
                           refusal: str | None) -> None:
        """How the kit's wearables followed the tray, once calibrated together (or why they could not be)."""
        with self._tx() as s:
            row = s.get_one(KitRow, kit_id, with_for_update=True)
            row.consistency, row.departed, row.refusal = consistency, list(departed), refusal

    def kit(self, kit_id: str) -> tuple[StoredKit, list[StoredSession]] | None:
        """A kit and its wearables' sessions, in the kit's order (None: no such kit)."""
        with self._read() as s:
            row = s.get(KitRow, kit_id)
            if row is None:
                return None
            ids = [m["session_id"] for m in row.members]
            sessions = {r.id: session_dict(r) for r in s.execute(select(SessionRow).where(SessionRow.id.in_(ids))).scalars()}
            kit = StoredKit(id=row.id, operator=row.operator, gateway=row.gateway, started_at=iso_utc(row.started_at),
                            members=list(row.members), consistency=row.consistency, departed=list(row.departed or []),
                            refusal=row.refusal)
            return kit, [sessions[i] for i in ids if i in sessions]
