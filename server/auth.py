"""Operators and their tokens.

An operator has a name and a secret of at least 12 characters (stored as a salted scrypt hash). Signing
in with both gives a random bearer token (stored as its SHA-256, valid for Settings.token_ttl_s). When
GYROCAL_API_TOKEN is set, that value is also accepted as the bearer token of an operator named "api".

An operator may also have a PIN of 4 to 8 digits (also a salted scrypt hash), for tablets: it is accepted
only from the client addresses the service trusts with PINs (this computer unless `--pin-from` adds
networks), after 3 free failures each try waits 1, 2, 4, ... s, and after 10 wrong PINs in a row the PIN is
switched off until the operator (with their secret) or an administrator sets a new one.

Sign-ins over HTTP go through ``SignIns``: failed ones are audited and throttled per operator name and
per client address (growing delays, answered 429 with Retry-After), and scrypt runs in a small pool of
its own so a flood of sign-ins cannot hold up the threads every database call uses.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import hashlib
import hmac
import ipaddress
import re
import secrets
from collections.abc import AsyncIterator, Callable
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime, timedelta

from .store import NotFound, Store
from .throttle import SignInThrottle

API_OPERATOR = "api"
_SCRYPT = {"n": 2**14, "r": 8, "p": 1, "dklen": 32}
NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9._@-]{0,63}$"
NAME_RE = re.compile(NAME_PATTERN)
MIN_SECRET = 12
OPERATOR_FREE_FAILURES = 5  # then 1, 2, 4, ... s between attempts, up to MAX_DELAY_S
ADDRESS_FREE_FAILURES = 20  # one tablet may be shared by several operators
MAX_DELAY_S = 300.0
PIN_RE = re.compile(r"^[0-9]{4,8}$")
PIN_FREE_FAILURES = 3
PIN_MAX_FAILURES = 10  # wrong PINs in a row that switch an operator's PIN off
PIN_FROM_DEFAULT = ("127.0.0.0/8", "::1/128")
HASH_THREADS = 2
HASH_QUEUE = 8  # sign-ins verifying or waiting to, at most; more get 429


class AuthError(Exception):
    """Missing or wrong credentials; the message says what to do."""


class PinRefused(AuthError):
    """A PIN from an address the service does not trust with PINs."""


class Throttled(AuthError):
    """Too many failed sign-ins (or too many at once): try again after ``retry_after_s``."""

    def __init__(self, message: str, retry_after_s: float) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s


def _check_secret(secret: str) -> str:
    if len(secret) < MIN_SECRET:
        raise AuthError(f"an operator secret needs at least {MIN_SECRET} characters")
    return secret


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


def check_pin(pin: str) -> str:
    if not PIN_RE.match(pin or ""):
        raise AuthError("a PIN is 4 to 8 digits")
    return pin


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
        secret = _check_secret(secret or new_secret())
        self.store.add_operator(name, hash_secret(secret))
        return secret

    def reset_operator(self, name: str, secret: str | None = None) -> str:
        secret = _check_secret(secret or new_secret())
        self.store.reset_operator(name, hash_secret(secret))
        return secret

    def set_pin(self, name: str, pin: str | None) -> None:
        """Give an operator a PIN, or take it away (None)."""
        self.store.set_operator_pin(name, None if pin is None else hash_secret(check_pin(pin)),
                                    "operator.pin_set" if pin is not None else "operator.pin_removed")

    def sign_in(self, name: str, secret: str, client: str | None = None) -> tuple[str, datetime]:
        """A new bearer token for an operator and its expiry; AuthError on a wrong name or secret (no throttle:
        the CLI and tests; the service signs in through SignIns)."""
        if not secret_matches(secret, self.store.operator_secret_hash(name)):
            raise AuthError("unknown operator or wrong secret")
        return self.issue(name, client)

    def issue(self, name: str, client: str | None = None) -> tuple[str, datetime]:
        """A new bearer token for an operator whose secret was checked."""
        token = secrets.token_urlsafe(32)
        expires = datetime.now(UTC) + timedelta(seconds=self.token_ttl_s)
        try:
            self.store.add_token(name, token_hash(token), expires, client)
        except NotFound as exc:  # disabled between the check of its secret and now; a store outage is the store's to say
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


def secret_matches(secret: str, stored: str | None) -> bool:
    """Whether a secret matches an operator's stored hash; an unknown operator (None) is checked against a dummy
    hash too, so timing does not reveal which names exist."""
    return verify_secret(secret, stored or _DUMMY_HASH) and stored is not None


class SignIns:
    """The service's sign-ins: throttled per operator and per client address, failures audited, scrypt in its
    own bounded pool."""

    def __init__(self, auth: Authenticator, pin_from: tuple[str, ...] = PIN_FROM_DEFAULT) -> None:
        self.auth = auth
        self.by_operator = SignInThrottle(OPERATOR_FREE_FAILURES, MAX_DELAY_S)
        self.by_address = SignInThrottle(ADDRESS_FREE_FAILURES, MAX_DELAY_S)
        self.by_pin = SignInThrottle(PIN_FREE_FAILURES, MAX_DELAY_S)
        self.pin_networks = tuple(ipaddress.ip_network(n, strict=False) for n in pin_from)
        self._pool = ThreadPoolExecutor(HASH_THREADS, thread_name_prefix="gyrocal-scrypt")
        self._busy = 0
        self._checking: dict[str, tuple[asyncio.Lock, int]] = {}  # operator -> its lock, and the sign-ins holding or awaiting it

    @contextlib.asynccontextmanager
    async def _one_at_a_time(self, op_key: str) -> AsyncIterator[None]:
        """One sign-in of an operator checked at a time: each sees the failures of those before it, so guesses sent
        together get no more tries before the waits begin than guesses sent one after another."""
        lock, users = self._checking.get(op_key, (asyncio.Lock(), 0))
        self._checking[op_key] = (lock, users + 1)
        try:
            async with lock:
                yield
        finally:
            lock, users = self._checking[op_key]
            if users == 1:
                del self._checking[op_key]
            else:
                self._checking[op_key] = (lock, users - 1)

    def pin_allowed_from(self, client: str) -> bool:
        """Whether PINs are accepted from this client address."""
        try:
            addr = ipaddress.ip_address(client)
        except ValueError:
            return False
        return any(addr in net for net in self.pin_networks)

    def _wait(self, *throttled: tuple[SignInThrottle, str]) -> None:
        wait = max(t.retry_after(key) for t, key in throttled)
        if wait > 0:
            raise Throttled(f"too many failed sign-ins for this operator or from this computer: try again in {wait:.0f} s", wait)
        if self._busy >= HASH_QUEUE:
            raise Throttled("too many sign-ins at once: try again in a moment", 1.0)

    async def _matches(self, given: str, lookup: Callable[[str], str | None], name: str) -> bool:
        self._busy += 1
        try:
            stored = await asyncio.to_thread(lookup, name)
            return await asyncio.get_running_loop().run_in_executor(self._pool, secret_matches, given, stored)
        finally:
            self._busy -= 1

    async def _failed(self, name: str, client: str, what: str, failures: int) -> None:
        await asyncio.to_thread(self.auth.store.audit, None, "auth.sign_in_failed", None, None,
                                {"operator": name, "client": client, "failures": failures, "with": what})

    async def sign_in(self, name: str, secret: str, client: str) -> tuple[str, datetime]:
        """A token for a correct name and secret; Throttled or AuthError otherwise."""
        op_key, addr_key = name.lower(), client
        async with self._one_at_a_time(op_key):
            self._wait((self.by_operator, op_key), (self.by_address, addr_key))
            if not await self._matches(secret, self.auth.store.operator_secret_hash, name):
                self.by_operator.failed(op_key)
                self.by_address.failed(addr_key)
                await self._failed(name, client, "secret", self.by_operator.failures(op_key))
                raise AuthError("unknown operator or wrong secret")
            self.by_operator.succeeded(op_key)
            self.by_pin.succeeded(op_key)  # the secret proves the operator: their PIN tries start afresh
        return await asyncio.to_thread(self.auth.issue, name, client)

    async def sign_in_pin(self, name: str, pin: str, client: str) -> tuple[str, datetime]:
        """A token for a correct name and PIN from a trusted address; Throttled, PinRefused or AuthError otherwise."""
        if not self.pin_allowed_from(client):
            raise PinRefused("PINs are accepted only on the tablets this service trusts; sign in with your secret, "
                             "or ask the administrator to allow this tablet (gyrocal serve --pin-from)")
        op_key, addr_key = name.lower(), client
        async with self._one_at_a_time(op_key):
            self._wait((self.by_pin, op_key), (self.by_address, addr_key))
            if not await self._matches(pin, self.auth.store.operator_pin_hash, name):
                self.by_pin.failed(op_key)
                self.by_address.failed(addr_key)
                failures = self.by_pin.failures(op_key)
                await self._failed(name, client, "pin", failures)
                pin_hash: str | None = None
                if failures >= PIN_MAX_FAILURES:
                    pin_hash = await asyncio.to_thread(self.auth.store.operator_pin_hash, name)
                if pin_hash is not None:
                    await asyncio.to_thread(self.auth.store.set_operator_pin, name, None, "operator.pin_locked")
                    self.by_pin.succeeded(op_key)
                    raise AuthError(f"{PIN_MAX_FAILURES} wrong PINs in a row: the PIN of this operator is now switched off. "
                                    "Sign in with your secret and set a new PIN")
                raise AuthError("unknown operator, no PIN set, or wrong PIN")
            self.by_pin.succeeded(op_key)
        return await asyncio.to_thread(self.auth.issue, name, client)

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)


# a decoy in hash_secret's form: an unknown name costs the same scrypt as a known one, and no secret matches random bytes
_DUMMY_HASH = "$".join(["scrypt", *(str(_SCRYPT[key]) for key in ("n", "r", "p")),
                        base64.b64encode(secrets.token_bytes(16)).decode(),
                        base64.b64encode(secrets.token_bytes(_SCRYPT["dklen"])).decode()])
