"""Operators and their tokens.

An operator has a name and a secret (stored as a salted scrypt hash). Signing in with both gives a
random bearer token (stored as its SHA-256, valid for Settings.token_ttl_s). When GYROCAL_API_TOKEN
is set, that value is also accepted as the bearer token of an operator named "api".
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import re
import secrets
from datetime import datetime, timedelta, timezone

from .store import Store, StoreError

API_OPERATOR = "api"
_SCRYPT = {"n": 2**14, "r": 8, "p": 1, "dklen": 32}
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._@-]{0,63}$")


class AuthError(Exception):
    """Missing or wrong credentials; the message says what to do."""


def hash_secret(secret: str) -> str:
    """A salted scrypt hash of an operator's secret, self-describing: scrypt$n$r$p$salt$hash."""
    salt = secrets.token_bytes(16)
    digest = hashlib.scrypt(secret.encode(), salt=salt, **_SCRYPT)
    enc = lambda b: base64.b64encode(b).decode()  # noqa: E731
    return f"scrypt${_SCRYPT['n']}${_SCRYPT['r']}${_SCRYPT['p']}${enc(salt)}${enc(digest)}"


def verify_secret(secret: str, stored: str) -> bool:
    """Whether a secret matches a hash made by hash_secret (constant time)."""
    try:
        scheme, n, r, p, salt, digest = stored.split("$")
        if scheme != "scrypt":
            return False
        want = base64.b64decode(digest)
        got = hashlib.scrypt(secret.encode(), salt=base64.b64decode(salt), n=int(n), r=int(r), p=int(p), dklen=len(want))
    except (ValueError, TypeError):
        return False
    return hmac.compare_digest(got, want)


def new_secret() -> str:
    """A fresh random operator secret (URL-safe, 32 bytes of entropy)."""
    return secrets.token_urlsafe(32)


def token_hash(token: str) -> str:
    # Bearer tokens are 256-bit random values, so a plain SHA-256 is enough to store them.
    return hashlib.sha256(token.encode()).hexdigest()


def check_name(name: str) -> str:
    if not NAME_RE.match(name or ""):
        raise AuthError("an operator name is 1-64 letters, digits or . _ @ - and starts with a letter or digit")
    if name == API_OPERATOR:
        raise AuthError(f'"{API_OPERATOR}" is reserved for the GYROCAL_API_TOKEN operator; choose another name')
    return name


class Authenticator:
    """Signs operators in and resolves bearer tokens to operator names."""

    def __init__(self, store: Store, api_token: str | None = None, token_ttl_s: float = 12 * 3600.0) -> None:
        self.store = store
        self.api_token = api_token
        self.token_ttl_s = token_ttl_s

    def add_operator(self, name: str, secret: str | None = None) -> str:
        """Create an operator; returns the secret (generated when not given)."""
        check_name(name)
        secret = secret or new_secret()
        if len(secret) < 8:
            raise AuthError("an operator secret needs at least 8 characters")
        self.store.add_operator(name, hash_secret(secret))
        return secret

    def reset_operator(self, name: str, secret: str | None = None) -> str:
        secret = secret or new_secret()
        if len(secret) < 8:
            raise AuthError("an operator secret needs at least 8 characters")
        self.store.reset_operator(name, hash_secret(secret))
        return secret

    def sign_in(self, name: str, secret: str) -> tuple[str, datetime]:
        """A new bearer token for an operator and its expiry; AuthError on a wrong name or secret."""
        stored = self.store.operator_secret_hash(name)
        # Verify against a dummy hash for unknown names too, so timing does not reveal which names exist.
        ok = verify_secret(secret, stored or _DUMMY_HASH) and stored is not None
        if not ok:
            raise AuthError("unknown operator or wrong secret")
        token = secrets.token_urlsafe(32)
        expires = datetime.now(timezone.utc) + timedelta(seconds=self.token_ttl_s)
        try:
            self.store.add_token(name, token_hash(token), expires)
        except StoreError as exc:
            raise AuthError(str(exc)) from exc
        return token, expires

    def sign_out(self, token: str, operator: str | None) -> None:
        self.store.revoke_token(token_hash(token), operator)

    def operator_for(self, token: str | None) -> str | None:
        """The operator a bearer token belongs to, or None."""
        if not token:
            return None
        if self.api_token and hmac.compare_digest(token.encode(), self.api_token.encode()):
            return API_OPERATOR
        return self.store.operator_for_token(token_hash(token))


_DUMMY_HASH = hash_secret(secrets.token_urlsafe(16))
