"""Operators, their secrets and PINs, and the sign-in tokens they are given."""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import select
from sqlalchemy.orm import Session

from .base import StoreBase
from .errors import NotFound, StoreError
from .records import StoredOperator, iso_utc
from .tables import AuthToken, Operator, aware, utcnow


class OperatorStore(StoreBase):
    """The operators' part of the store."""

    def add_operator(self, name: str, secret_hash: str) -> None:
        with self._tx("audit_log") as s:
            existing = s.execute(select(Operator).where(Operator.name == name)).scalar_one_or_none()
            if existing is not None and existing.disabled_at is None:
                raise StoreError(f"operator {name!r} exists already; use `gyrocal operator reset {name}` for a new secret")
            if existing is not None:
                existing.secret_hash = secret_hash
                existing.disabled_at = None
            else:
                s.add(Operator(name=name, secret_hash=secret_hash, created_at=utcnow()))
            self._audit(s, None, "operator.add", detail={"operator": name})

    def _active_operator(self, s: Session, name: str) -> Operator:
        op = s.execute(select(Operator).where(Operator.name == name, Operator.disabled_at.is_(None))).scalar_one_or_none()
        if op is None:
            raise NotFound(f"no operator named {name!r}; add one with `gyrocal operator add {name}`")
        return op

    def reset_operator(self, name: str, secret_hash: str) -> None:
        with self._tx("audit_log") as s:
            op = self._active_operator(s, name)
            op.secret_hash = secret_hash
            self._revoke_tokens(s, op.id)
            self._audit(s, None, "operator.reset", detail={"operator": name})

    def disable_operator(self, name: str) -> None:
        with self._tx("audit_log") as s:
            op = self._active_operator(s, name)
            op.disabled_at = utcnow()
            self._revoke_tokens(s, op.id)
            self._audit(s, None, "operator.remove", detail={"operator": name})

    @staticmethod
    def _revoke_tokens(s: Session, operator_id: int) -> None:
        for tok in s.execute(select(AuthToken).where(AuthToken.operator_id == operator_id, AuthToken.revoked_at.is_(None))).scalars():
            tok.revoked_at = utcnow()

    def operators(self) -> list[StoredOperator]:
        with self._read() as s:
            rows = s.execute(select(Operator).order_by(Operator.name)).scalars().all()
            return [StoredOperator(name=r.name, created_at=iso_utc(r.created_at), active=r.disabled_at is None) for r in rows]

    def operator_secret_hash(self, name: str) -> str | None:
        """The stored hash of an active operator's secret, or None."""
        with self._read() as s:
            return s.execute(
                select(Operator.secret_hash).where(Operator.name == name, Operator.disabled_at.is_(None))
            ).scalar_one_or_none()

    def set_operator_pin(self, name: str, pin_hash: str | None, why: str = "operator.pin_set") -> None:
        """Give an active operator a PIN (its hash), or take it away (None); audited as ``why``."""
        with self._tx("audit_log") as s:
            self._active_operator(s, name).pin_hash = pin_hash
            self._audit(s, None, why, detail={"operator": name})

    def operator_pin_hash(self, name: str) -> str | None:
        """The stored hash of an active operator's PIN, or None (no such operator, or no PIN)."""
        with self._read() as s:
            return s.execute(select(Operator.pin_hash).where(Operator.name == name, Operator.disabled_at.is_(None))).scalar_one_or_none()

    def add_token(self, operator: str, token_hash: str, expires_at: datetime, client: str | None = None) -> None:
        with self._tx("audit_log") as s:
            op = self._active_operator(s, operator)
            s.add(AuthToken(token_hash=token_hash, operator_id=op.id, created_at=utcnow(), expires_at=expires_at))
            self._audit(s, operator, "auth.sign_in", detail={"client": client} if client else None)

    def operator_for_token(self, token_hash: str) -> str | None:
        """The name of the operator holding this (unexpired, unrevoked) token, or None."""
        with self._read() as s:
            row = s.execute(
                select(Operator.name, AuthToken.expires_at)
                .join(Operator, Operator.id == AuthToken.operator_id)
                .where(AuthToken.token_hash == token_hash, AuthToken.revoked_at.is_(None), Operator.disabled_at.is_(None))
            ).one_or_none()
        if row is None or aware(row.expires_at) <= utcnow():
            return None
        return str(row.name)

    def revoke_token(self, token_hash: str, operator: str | None) -> None:
        with self._tx("audit_log") as s:
            tok = s.get(AuthToken, token_hash)
            if tok is not None and tok.revoked_at is None:
                tok.revoked_at = utcnow()
                self._audit(s, operator, "auth.sign_out")
