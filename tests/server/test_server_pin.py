"""Signing in with a short PIN on a tablet: set by the operator (or an administrator), accepted only from the
addresses the service trusts with PINs, throttled sooner than a secret, and switched off after ten wrong PINs."""

from __future__ import annotations

import asyncio
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
from server_fixtures import GYROCAL, ROOT, RunningService, at_once

from server.auth import PIN_MAX_FAILURES, Authenticator, AuthError, PinRefused, SignIns, Throttled
from server.store import Store

SECRET = "a long enough secret"


def _cli(db: str, *args: str, stdin: str = "") -> subprocess.CompletedProcess[str]:
    return subprocess.run([*GYROCAL, "operator", "--db", db, *args], input=stdin, cwd=ROOT, capture_output=True, text=True, timeout=60)


@pytest.fixture(scope="module")
def pin_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A store with alice (who has a PIN) and bob, made once through the CLI; each test gets a copy of its own."""
    path = tmp_path_factory.mktemp("pin") / "store.sqlite3"
    db = f"sqlite:///{path}"
    for name in ("alice", "bob"):
        assert _cli(db, "add", name, "--secret-stdin", stdin=SECRET + "\n").returncode == 0
    r = _cli(db, "pin", "alice", "--pin-stdin", stdin="4831\n")
    assert r.returncode == 0 and "has a new PIN" in r.stdout, r.stderr
    return path


@pytest.fixture
def pin_service(pin_store: Path, tmp_path: Path) -> Iterator[RunningService]:
    copy = tmp_path / "store.sqlite3"
    shutil.copyfile(pin_store, copy)
    svc = RunningService([], f"sqlite:///{copy}").start()
    yield svc
    svc.stop()


def test_an_operator_signs_in_with_the_pin_an_administrator_set(pin_service: RunningService) -> None:
    with pin_service.client(token=None) as c:
        r = c.post("/auth/login", json={"operator": "alice", "pin": "4831"})
        assert r.status_code == 200, r.text
        assert c.get("/auth/me", headers={"Authorization": f"Bearer {r.json()['token']}"}).json() == {"operator": "alice"}
        # bob has no PIN: no PIN signs him in
        assert c.post("/auth/login", json={"operator": "bob", "pin": "4831"}).status_code == 401


def test_an_operator_sets_their_own_pin_and_the_api_operator_cannot(pin_service: RunningService) -> None:
    with pin_service.client(token=None) as c:
        token = c.post("/auth/login", json={"operator": "bob", "secret": SECRET}).json()["token"]
        bearer = {"Authorization": f"Bearer {token}"}
        assert c.put("/auth/pin", json={"pin": "12"}, headers=bearer).status_code == 422  # too short: says so, keeps nothing
        assert c.put("/auth/pin", json={"pin": "2468"}, headers=bearer).status_code == 204
        assert c.post("/auth/login", json={"operator": "bob", "pin": "2468"}).status_code == 200
        assert c.delete("/auth/pin", headers=bearer).status_code == 204
        assert c.post("/auth/login", json={"operator": "bob", "pin": "2468"}).status_code == 401
        assert c.put("/auth/pin", json={"pin": "2468"}).status_code == 401
    with pin_service.client() as c:  # the API token's operator
        assert c.put("/auth/pin", json={"pin": "2468"}).status_code == 403
        actions = [e["action"] for e in c.get("/audit", params={"limit": 50}).json()]
    assert "operator.pin_set" in actions and "operator.pin_removed" in actions


MALFORMED_PIN_SIGN_INS = [
    {"operator": "alice", "pin": "48a1"},
    {"operator": "alice", "pin": "123456789"},
    {"operator": "alice", "pin": "4831", "secret": SECRET},
]


def test_malformed_pin_sign_ins_are_422(pin_service: RunningService) -> None:
    with pin_service.client(token=None) as c:  # one service for the three: a refused body changes nothing stored
        for body in MALFORMED_PIN_SIGN_INS:
            assert c.post("/auth/login", json=body).status_code == 422, body
        assert c.post("/auth/login", json={"operator": "alice", "pin": "4831"}).status_code == 200


def test_guessing_a_pin_is_throttled_after_three_failures(pin_service: RunningService) -> None:
    with pin_service.client(token=None) as c:
        codes = [c.post("/auth/login", json={"operator": "alice", "pin": f"{i:04d}"}).status_code for i in range(6)]
        assert codes[:3] == [401] * 3 and 429 in codes[3:]
        # the right PIN is refused too while throttled; the secret still works and starts the PIN's count afresh
        assert c.post("/auth/login", json={"operator": "alice", "pin": "4831"}).status_code == 429
        assert c.post("/auth/login", json={"operator": "alice", "secret": SECRET}).status_code == 200
        assert c.post("/auth/login", json={"operator": "alice", "pin": "4831"}).status_code == 200


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_ten_wrong_pins_switch_the_pin_off_and_only_trusted_addresses_may_use_one(tmp_path: Path) -> None:
    store = Store(f"sqlite:///{tmp_path / 'store.sqlite3'}")
    auth = Authenticator(store)
    auth.add_operator("carol", SECRET)
    auth.set_pin("carol", "975310")
    sign_ins = SignIns(auth, pin_from=("127.0.0.0/8", "10.1.2.0/24"))
    clock = _Clock()
    sign_ins.by_pin.clock = clock
    sign_ins.by_address.clock = clock

    async def attempt(pin: str, client: str = "10.1.2.7") -> str:
        try:
            await sign_ins.sign_in_pin("carol", pin, client)
        except Throttled:
            return "throttled"
        except PinRefused:
            return "refused"
        except AuthError as exc:
            return str(exc)
        return "signed in"

    async def run() -> None:
        assert await attempt("975310", client="192.168.0.9") == "refused"  # not a trusted tablet: not even checked
        assert await attempt("975310") == "signed in"
        answers = []
        for i in range(PIN_MAX_FAILURES):
            clock.t += 600.0  # each guess after the throttle's wait
            answers.append(await attempt(f"{i:06d}"))
        assert all("wrong PIN" in a for a in answers[:-1]) and "switched off" in answers[-1]
        clock.t += 600.0
        assert await attempt("975310") != "signed in"  # the right PIN no longer works
        assert store.operator_pin_hash("carol") is None
        token, _ = await sign_ins.sign_in("carol", SECRET, "10.1.2.7")  # the secret still does
        assert auth.operator_for(token) == "carol"

    try:
        asyncio.run(run())
        assert "operator.pin_locked" in [e["action"] for e in store.audit_log(limit=100)]
    finally:
        sign_ins.close()
        store.close()


def test_guesses_sent_at_once_get_no_more_tries_than_one_after_another(service_store: tuple[str, str]) -> None:
    """Twelve wrong PINs fired together on SQLite and PostgreSQL: exactly 3 are checked, as when sent one after
    another, the rest wait; then even the right PIN waits."""
    owner_url, service_url = service_store
    assert _cli(owner_url, "add", "dora", "--secret-stdin", stdin=SECRET + "\n").returncode == 0
    assert _cli(owner_url, "pin", "dora", "--pin-stdin", stdin="5151\n").returncode == 0
    svc = RunningService([], service_url).start()
    try:
        with svc.client(token=None) as c:
            codes = at_once([lambda pin=f"{i:04d}": c.post("/auth/login", json={"operator": "dora", "pin": pin}).status_code
                             for i in range(12)])
            assert sorted(codes) == [401] * 3 + [429] * 9, codes
            assert c.post("/auth/login", json={"operator": "dora", "pin": "5151"}).status_code == 429
    finally:
        svc.stop()
