"""Sign-in as an attacker would try it: guessing is throttled and audited, floods are bounded, secrets are long."""

from __future__ import annotations

import subprocess
import threading
from pathlib import Path

import httpx
import pytest
from server_fixtures import GYROCAL, ROOT, RunningService

from server.throttle import SignInThrottle, TokenBucket

SECRET = "a long enough secret"


def _service(tmp_path: Path, *operators: str) -> RunningService:
    db = f"sqlite:///{tmp_path / 'store.sqlite3'}"
    for name in operators:
        r = subprocess.run([*GYROCAL, "operator", "--db", db, "add", name, "--secret-stdin"], input=SECRET + "\n", cwd=ROOT,
                           capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stderr
    return RunningService([], db).start()


def test_guessing_a_secret_is_throttled_with_growing_delays_and_audited(tmp_path: Path) -> None:
    svc = _service(tmp_path, "alice", "bob")
    try:
        with svc.client(token=None) as c:
            codes, waits = [], []
            for i in range(12):
                r = c.post("/auth/login", json={"operator": "alice", "secret": f"wrong guess {i:04d}"})
                codes.append(r.status_code)
                if r.status_code == 429:
                    waits.append(int(r.headers["Retry-After"]))
                    assert "try again in" in r.json()["detail"]
            # five free failures, the sixth waits 1 s after the fifth; guessing at full speed is refused from then on
            assert codes[:5] == [401] * 5 and 429 in codes[5:]
            assert codes[5:].count(401) <= 1 and all(w >= 1 for w in waits)
            # even the right secret is refused while the operator is throttled: no oracle for the guesser
            r = c.post("/auth/login", json={"operator": "alice", "secret": SECRET})
            assert r.status_code == 429
            # another operator on the same computer is not locked out by alice's failures
            assert c.post("/auth/login", json={"operator": "bob", "secret": SECRET}).status_code == 200
        with svc.client() as c:
            failed = [e for e in c.get("/audit", params={"limit": 100}).json() if e["action"] == "auth.sign_in_failed"]
        assert len(failed) == codes.count(401)
        assert {e["detail"]["operator"] for e in failed} == {"alice"} and failed[0]["detail"]["client"] == "127.0.0.1"
    finally:
        svc.stop()


def test_a_flood_of_sign_ins_is_bounded_and_never_an_error(tmp_path: Path) -> None:
    svc = _service(tmp_path, "carol")
    answers: list[httpx.Response] = []
    lock = threading.Lock()
    barrier = threading.Barrier(32)

    def one() -> None:
        with httpx.Client(base_url=svc.base, timeout=60, verify=False) as c:
            barrier.wait()
            r = c.post("/auth/login", json={"operator": "carol", "secret": SECRET})
            with lock:
                answers.append(r)

    try:
        threads = [threading.Thread(target=one) for _ in range(32)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(120)
        codes = [r.status_code for r in answers]
        assert len(codes) == 32 and set(codes) <= {200, 429}, codes
        assert codes.count(200) >= 8
        assert all("Retry-After" in r.headers for r in answers if r.status_code == 429)
        with httpx.Client(base_url=svc.base, timeout=10, verify=False) as c:
            assert c.get("/health").json()["status"] == "ok"
    finally:
        svc.stop()


@pytest.mark.parametrize("body", [
    {"operator": "al\u0000ice", "secret": "x"},
    {"operator": "", "secret": "x"},
    {"operator": "alice", "secret": ""},
    {"operator": "alice"},
])
def test_malformed_sign_ins_are_4xx(tmp_path: Path, body: dict[str, str]) -> None:
    svc = _service(tmp_path)
    try:
        with svc.client(token=None) as c:
            assert c.post("/auth/login", json=body).status_code == 422
    finally:
        svc.stop()


def test_operator_secrets_need_twelve_characters(tmp_path: Path) -> None:
    db = f"sqlite:///{tmp_path / 'store.sqlite3'}"
    r = subprocess.run([*GYROCAL, "operator", "--db", db, "add", "dave", "--secret-stdin"], input="eleven char\n", cwd=ROOT,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "at least 12 characters" in r.stderr
    r = subprocess.run([*GYROCAL, "operator", "--db", db, "add", "dave", "--secret-stdin"], input="twelve chars\n", cwd=ROOT,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr


def test_throttle_delays_double_up_to_their_limit_and_success_clears_them() -> None:
    now = [0.0]
    t = SignInThrottle(free=5, max_delay_s=300, clock=lambda: now[0])
    for _ in range(5):
        assert t.retry_after("k") == 0
        t.failed("k")
    assert t.retry_after("k") == 1.0
    t.failed("k")
    assert t.retry_after("k") == 2.0
    for _ in range(20):
        t.failed("k")
    assert t.retry_after("k") == 300.0
    now[0] += 301
    assert t.retry_after("k") == 0
    t.succeeded("k")
    assert t.failures("k") == 0
    b = TokenBucket(rate_per_min=6, burst=2, clock=lambda: now[0])
    assert b.take("ip") == 0 and b.take("ip") == 0
    assert b.take("ip") == pytest.approx(10.0)
    now[0] += 10
    assert b.take("ip") == 0
