"""The fleet's part of the store: gateways (one service per room) and their heartbeats, the wearables each one
sees, and the lease on each wearable that lets one gateway at a time run a session, a verification or a write.

A lease is one row per device, taken with one atomic upsert that only succeeds when the row is free, expired or
already this gateway's, so of two gateways asking at once exactly one gets it, on SQLite and PostgreSQL alike.
A gateway renews its leases with its heartbeat; when it dies they expire, and the next sweep (any gateway's)
ends the session it was running as failed, ``gateway_lost``, with the samples it had spooled archived.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any, cast

from sqlalchemy import CursorResult, delete, select, update

from .records import StoredGateway, StoredSighting, iso_utc
from .sessions import SessionStore
from .tables import GatewayRow, LeaseRow, SessionRow, SightingRow, aware


@dataclass(frozen=True)
class Lease:
    """Who may use a device, until when."""

    device_id: str
    gateway: str
    holder: str  # a session or verification id, or "write"
    expires_at: datetime


class FleetStore(SessionStore):
    """Gateways, sightings and leases."""

    # -- gateways -------------------------------------------------------------------------------
    def register_gateway(self, name: str, url: str | None, version: str) -> None:
        """A gateway starting (again): its URL and version; its heartbeat starts now."""
        with self._tx() as s:
            now = self._db_now(s)
            row = s.get(GatewayRow, name, with_for_update=True)
            if row is None:
                s.add(GatewayRow(name=name, url=url, version=version, started_at=now, heartbeat_at=now))
            else:
                row.url, row.version, row.started_at, row.heartbeat_at = url, version, now, now

    def heartbeat(self, name: str, lease_s: float, seen: dict[str, int | None], held: dict[str, str]) -> int:
        """The gateway is alive: its heartbeat, the wearables it sees now (id -> signal strength in dBm, or None), and
        the leases of what it still runs (device id -> holder) renewed for ``lease_s`` more seconds; a lease it no
        longer uses is left to expire. Returns how many leases it renewed."""
        renewed = 0
        with self._tx() as s:
            now = self._db_now(s)
            s.execute(update(GatewayRow).where(GatewayRow.name == name).values(heartbeat_at=now))
            for device_id, rssi in sorted(seen.items()):  # a fixed order: two gateways never wait on each other's rows
                row = s.get(SightingRow, (device_id, name))
                if row is None:
                    s.add(SightingRow(device_id=device_id, gateway=name, last_seen=now, rssi_dbm=rssi))
                else:
                    row.last_seen, row.rssi_dbm = now, rssi
            for device_id, holder in sorted(held.items()):
                done = s.execute(update(LeaseRow).where(LeaseRow.device_id == device_id, LeaseRow.gateway == name,
                                                        LeaseRow.holder == holder)
                                 .values(expires_at=now + timedelta(seconds=lease_s)).execution_options(synchronize_session=False))
                renewed += cast(CursorResult[Any], done).rowcount
            return renewed

    def gateways(self) -> list[StoredGateway]:
        with self._read() as s:
            return [StoredGateway(name=r.name, url=r.url, version=r.version, started_at=iso_utc(r.started_at),
                                  heartbeat_at=iso_utc(r.heartbeat_at))
                    for r in s.execute(select(GatewayRow).order_by(GatewayRow.name)).scalars()]

    def sightings(self) -> list[StoredSighting]:
        with self._read() as s:
            q = select(SightingRow).order_by(SightingRow.device_id, SightingRow.last_seen.desc())
            return [StoredSighting(device_id=r.device_id, gateway=r.gateway, last_seen=iso_utc(r.last_seen), rssi_dbm=r.rssi_dbm)
                    for r in s.execute(q).scalars()]

    def known_sessions(self, ids: list[str]) -> set[str]:
        """Which of ``ids`` are calibration sessions (live or uploaded) in the store."""
        if not ids:
            return set()
        with self._read() as s:
            return set(s.execute(select(SessionRow.id).where(SessionRow.id.in_(ids))).scalars())

    # -- leases ---------------------------------------------------------------------------------
    def take_lease(self, device_id: str, gateway: str, holder: str, lease_s: float) -> Lease:
        """The device's lease for ``holder`` on ``gateway`` (granted when free, expired or already this gateway's);
        otherwise the lease that stands in the way (its gateway differs from ``gateway``)."""
        with self._tx() as s:
            now = self._db_now(s)
            expires = now + timedelta(seconds=lease_s)
            values = {"device_id": device_id, "gateway": gateway, "holder": holder, "expires_at": expires}
            stmt = self._insert(LeaseRow).values(**values).on_conflict_do_update(
                index_elements=[LeaseRow.device_id],
                set_={"gateway": gateway, "holder": holder, "expires_at": expires},
                where=(LeaseRow.expires_at < now) | (LeaseRow.gateway == gateway),
            )
            s.execute(stmt)
            row = s.execute(select(LeaseRow).where(LeaseRow.device_id == device_id)).scalar_one()
            return Lease(row.device_id, row.gateway, row.holder, aware(row.expires_at))

    def release_lease(self, device_id: str, gateway: str, holder: str) -> None:
        """Give a lease back (the session, verification or write ended); someone else's lease is left alone."""
        with self._tx() as s:
            s.execute(delete(LeaseRow).where(LeaseRow.device_id == device_id, LeaseRow.gateway == gateway, LeaseRow.holder == holder))

    def leases(self) -> list[Lease]:
        """The leases that stand now, on the database's clock (an expired one not yet swept is not among them)."""
        with self._read() as s:
            now = self._db_now(s)
            return [Lease(r.device_id, r.gateway, r.holder, aware(r.expires_at))
                    for r in s.execute(select(LeaseRow).where(LeaseRow.expires_at >= now).order_by(LeaseRow.device_id)).scalars()]

    def silent_gateways(self, silent_after_s: float) -> set[str]:
        """The gateways whose last heartbeat is older than ``silent_after_s`` on the database's clock."""
        with self._read() as s:
            since = self._db_now(s) - timedelta(seconds=silent_after_s)
            return set(s.execute(select(GatewayRow.name).where(GatewayRow.heartbeat_at <= since)).scalars())

    def sweep_expired_leases(self) -> list[Lease]:
        """Drop the leases whose gateway stopped renewing them, and end as failed (``gateway_lost``) the sessions
        they held that are still open; the leases dropped. Safe to run on every gateway at once: each lease is
        dropped (and its session ended) by exactly one of them."""
        with self._read() as s:  # most beats find none: then no history lock is waited for, behind sessions being written
            if s.execute(select(LeaseRow.device_id).where(LeaseRow.expires_at < self._db_now(s)).limit(1)).first() is None:
                return []
        with self._tx("recordings", "audit_log") as s:
            now = self._db_now(s)
            gone = s.execute(select(LeaseRow).where(LeaseRow.expires_at < now).with_for_update()).scalars().all()
            out = []
            for lease in gone:
                out.append(Lease(lease.device_id, lease.gateway, lease.holder, aware(lease.expires_at)))
                session = s.get(SessionRow, lease.holder, with_for_update=True)
                if session is not None and session.ended_at is None and session.gateway == lease.gateway:
                    self._end_with_spool(
                        s, session, "gateway_lost",
                        f"gateway {lease.gateway!r} stopped answering during the session (its lease on {lease.device_id} "
                        f"expired at {iso_utc(lease.expires_at)}); the device is free again: start a new session",
                    )
                s.delete(lease)
            return out
