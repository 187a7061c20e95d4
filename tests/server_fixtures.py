"""Fixtures of the service tests: a throwaway PostgreSQL server, store URLs, a running `gyrocal serve`.

Registered as a plugin by tests/conftest.py: the fixtures need no import; the helpers are imported by name.
"""

from __future__ import annotations

import contextlib
import glob
import io
import json
import os
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import httpx
import pytest

from calib.io.readers import write_native_csv

ROOT = Path(__file__).resolve().parents[1]
T = TypeVar("T")
GYROCAL = [sys.executable, "-m", "calib.cli.main"]
API_TOKEN = "test-token-" + uuid.uuid4().hex
# the logs of the services this test process starts (read by tests after a service stopped), removed as it ends
# (pytest_unconfigure: an xdist worker leaves without running atexit's handlers)
SERVICE_LOGS = tempfile.mkdtemp(prefix="gyrocal-serve-logs-")


def pytest_unconfigure(config: pytest.Config) -> None:
    shutil.rmtree(SERVICE_LOGS, ignore_errors=True)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


# -- PostgreSQL -----------------------------------------------------------------------------------
def _pg_bindir() -> Path:
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"), key=lambda p: int(Path(p).parts[-3]))
    if not found:
        pytest.fail("PostgreSQL is not installed: run `make test` (it installs Debian's postgresql) "
                    "or `sudo apt-get install postgresql`")
    return Path(found[-1]).parent


class PostgresServer:
    """A throwaway PostgreSQL cluster on a free port of 127.0.0.1 (trust auth, no fsync)."""

    def __init__(self) -> None:
        self.bindir = _pg_bindir()
        self.dir = Path(tempfile.mkdtemp(prefix="gyrocal-pg-"))
        self.data = self.dir / "data"
        self.port = free_port()
        self.as_root = os.geteuid() == 0

    def _run(self, *cmd: str) -> subprocess.CompletedProcess[str]:
        full = list(cmd)
        if self.as_root:  # PostgreSQL refuses to run as root
            full = ["runuser", "-u", "postgres", "--", *full]
        return subprocess.run(full, capture_output=True, text=True, timeout=120)

    def start(self) -> None:
        if self.as_root:
            shutil.chown(self.dir, "postgres", "postgres")
        r = self._run(str(self.bindir / "initdb"), "-D", str(self.data), "-A", "trust", "-U", "postgres", "--no-sync", "-E", "UTF8")
        if r.returncode:
            raise RuntimeError(f"initdb failed: {r.stderr}")
        self._pg_ctl_start()

    def _pg_ctl_start(self) -> None:
        opts = f"-p {self.port} -k {self.dir} -c listen_addresses=127.0.0.1 -c fsync=off -c full_page_writes=off"
        r = self._run(str(self.bindir / "pg_ctl"), "-D", str(self.data), "-o", opts, "-l", str(self.dir / "log"), "-w", "start")
        if r.returncode:
            log = (self.dir / "log").read_text() if (self.dir / "log").exists() else ""
            raise RuntimeError(f"pg_ctl start failed: {r.stderr}\n{log}")

    def restart(self, down_s: float = 0.0) -> None:
        """Stop the server (fast: clients are disconnected), stay down ``down_s`` seconds, start it again."""
        r = self._run(str(self.bindir / "pg_ctl"), "-D", str(self.data), "-m", "fast", "-w", "stop")
        if r.returncode:
            raise RuntimeError(f"pg_ctl stop failed: {r.stderr}")
        time.sleep(down_s)
        self._pg_ctl_start()

    def url(self, db: str = "postgres") -> str:
        return f"postgresql://postgres@127.0.0.1:{self.port}/{db}"

    def create_database(self) -> str:
        import psycopg

        name = "gyrocal_" + uuid.uuid4().hex[:12]
        with psycopg.connect(f"host=127.0.0.1 port={self.port} user=postgres dbname=postgres", autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{name}"')
        return self.url(name)

    def service_url(self, owner_url: str) -> str:
        """Set up the store at ``owner_url`` (as its owner) with a service role, the way an administrator would
        (`gyrocal store setup --service-role`), and return the URL the service connects with."""
        role = "svc_" + uuid.uuid4().hex[:10]
        r = subprocess.run([*GYROCAL, "store", "setup", "--db", owner_url, "--service-role", role],
                           cwd=ROOT, capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        return r.stdout.split("gyrocal serve --db '")[1].split("'")[0]

    def stop(self) -> None:
        self._run(str(self.bindir / "pg_ctl"), "-D", str(self.data), "-m", "immediate", "stop")
        shutil.rmtree(self.dir, ignore_errors=True)


@contextlib.contextmanager
def running_postgres() -> Iterator[PostgresServer]:
    """A throwaway PostgreSQL server, stopped and removed afterwards."""
    server = PostgresServer()
    server.start()
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture(scope="session")
def postgres() -> Iterator[PostgresServer]:
    """A real PostgreSQL server for the whole test session."""
    with running_postgres() as server:
        yield server


def wait_for(check: Callable[[], T], timeout_s: float, what: str) -> T:
    """Call ``check`` every 0.2 s until it returns something true, and return that; AssertionError naming ``what``
    when it does not within ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        got = check()
        if got:
            return got
        time.sleep(0.2)
    raise AssertionError(f"{what} within {timeout_s} s")


@pytest.fixture(params=["sqlite", "postgresql"])
def store_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    """An empty store: a SQLite file, and a fresh database on the PostgreSQL server."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'store.sqlite3'}"
    return request.getfixturevalue("postgres").create_database()


@pytest.fixture(params=["sqlite", "postgresql"])
def service_store(request: pytest.FixtureRequest, tmp_path: Path) -> tuple[str, str]:
    """(the owner's URL, the service's URL) of an empty store: one SQLite file, or a PostgreSQL database whose
    service role owns nothing (as `gyrocal store setup --service-role` makes it)."""
    if request.param == "sqlite":
        url = f"sqlite:///{tmp_path / 'store.sqlite3'}"
        return url, url
    pg = request.getfixturevalue("postgres")
    owner = pg.create_database()
    return owner, pg.service_url(owner)


# -- races and outages ------------------------------------------------------------------------------


def at_once(calls: list[Callable[[], T]], timeout_s: float = 90.0) -> list[T]:
    """Run each call in a thread of its own, all released together by a barrier; their results, in order."""
    barrier = threading.Barrier(len(calls))
    out: list[Any] = [None] * len(calls)

    def run(i: int) -> None:
        barrier.wait()
        out[i] = calls[i]()

    threads = [threading.Thread(target=run, args=(i,)) for i in range(len(calls))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout_s)
    return out


def store_outage(url: str, on: bool, writes: list[tuple[str, str, str | None]]) -> None:
    """Make the store at ``url`` (as the tables' owner) refuse some writes, or take them again: each write is
    (table, operation such as "INSERT" or "UPDATE OF ended_at", a condition on NEW or None), refused by a trigger
    the way a full disk or a lost connection would refuse it."""
    from sqlalchemy import create_engine, text

    eng = create_engine(url.replace("postgresql://", "postgresql+psycopg://"))
    with eng.begin() as conn:
        pg = eng.dialect.name == "postgresql"
        if pg and on:
            conn.execute(text("CREATE OR REPLACE FUNCTION test_outage() RETURNS trigger AS $$ "
                              "BEGIN RAISE EXCEPTION 'store down'; END; $$ LANGUAGE plpgsql"))
        for table, op, when in writes:
            name = f"test_outage_{table}_{op.split()[0].lower()}"
            conn.execute(text(f"DROP TRIGGER IF EXISTS {name}" + (f" ON {table}" if pg else "")))
            if not on:
                continue
            if pg:
                cond = f" WHEN ({when})" if when else ""
                conn.execute(text(f"CREATE TRIGGER {name} BEFORE {op} ON {table} FOR EACH ROW{cond} EXECUTE FUNCTION test_outage()"))
            else:
                cond = f" WHEN {when}" if when else ""
                conn.execute(text(f"CREATE TRIGGER {name} BEFORE {op} ON {table}{cond} BEGIN SELECT RAISE(ABORT, 'store down'); END"))
    eng.dispose()


# -- a running service ----------------------------------------------------------------------------
class RunningService:
    """`gyrocal serve` in a subprocess, reached over real HTTP. Its clients speak plain HTTP to this computer, so they
    are built without a TLS context (``verify=False``): loading the CA bundle costs 20 ms of CPU per client."""

    def __init__(self, args: list[str], db_url: str, env: dict[str, str] | None = None, prefix: list[str] | None = None) -> None:
        self.prefix = prefix or []  # a command the service runs under (prlimit, ...)
        self.port = free_port()
        self.db_url = db_url
        self.base = f"http://127.0.0.1:{self.port}"
        self.args = args
        self.env = {**os.environ, "GYROCAL_API_TOKEN": API_TOKEN, **(env or {})}
        self.proc: subprocess.Popen[str] | None = None
        self.log = tempfile.NamedTemporaryFile("w+", prefix="gyrocal-serve-", suffix=".log", dir=SERVICE_LOGS, delete=False)

    def start(self, timeout_s: float = 30.0) -> RunningService:
        cmd = [*self.prefix, *GYROCAL, "serve", "--port", str(self.port), "--db", self.db_url, "--log-level", "warning", *self.args]
        self.proc = subprocess.Popen(cmd, cwd=ROOT, env=self.env, stdout=self.log, stderr=subprocess.STDOUT, text=True)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"gyrocal serve exited with {self.proc.returncode}:\n{self.output()}")
            try:
                if httpx.get(self.base + "/health", timeout=1.0, verify=False).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.1)
        raise RuntimeError(f"gyrocal serve did not answer within {timeout_s} s:\n{self.output()}")

    def output(self) -> str:
        self.log.flush()
        return Path(self.log.name).read_text()

    def stop(self) -> int | None:
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode

    def client(self, token: str | None = API_TOKEN, timeout_s: float = 30.0) -> httpx.Client:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        return httpx.Client(base_url=self.base, headers=headers, timeout=timeout_s, verify=False)


def follow_events(base: str, sid: str, until: set[str], timeout_s: float = 60.0, last_event_id: int | None = None,
                  stop_after: int | None = None, params: dict[str, str] | None = None) -> list[dict[str, Any]]:
    """Read a session's SSE stream until its state is in ``until`` (or ``stop_after`` events). A 503 (the store
    restarting) is retried after a second, resuming after the last event read, as the page does."""
    events: list[dict[str, Any]] = []
    deadline = time.monotonic() + timeout_s
    while True:
        resume = events[-1]["_sse_id"] if events else last_event_id
        headers = {"Last-Event-ID": str(resume)} if resume is not None else {}
        with httpx.stream("GET", f"{base}/sessions/{sid}/events", headers=headers, params=params,
                          timeout=httpx.Timeout(timeout_s), verify=False) as r:
            if r.status_code == 503 and time.monotonic() + 1.0 < deadline:
                r.read()
                time.sleep(1.0)
                continue
            assert r.status_code == 200, r.read()
            assert r.headers["content-type"].startswith("text/event-stream")
            if _read_events(r, sid, until, deadline, stop_after, events):
                return events
        raise AssertionError(f"the event stream of {sid} ended before {until}; last: {events[-1:]}")


def _read_events(r: httpx.Response, sid: str, until: set[str], deadline: float, stop_after: int | None,
                 events: list[dict[str, Any]]) -> bool:
    """Append the stream's snapshots to ``events``; True once one's state is in ``until`` (or ``stop_after`` read)."""
    current: dict[str, str] = {}
    for line in r.iter_lines():
        if time.monotonic() > deadline:
            raise TimeoutError(f"session {sid} did not reach {until}; last: {events[-1:]}")
        if line == "":
            if "data" in current:
                snap = json.loads(current["data"])
                snap["_sse_id"] = int(current["id"])
                snap["_sse_event"] = current.get("event")
                events.append(snap)
                if snap["state"] in until or (stop_after is not None and len(events) >= stop_after):
                    return True
            current = {}
            continue
        if line.startswith(":"):
            continue
        key, _, value = line.partition(":")
        current[key] = value[1:] if value.startswith(" ") else value
    return False


def native_csv(rec: Any) -> str:
    """A Recording as the native CSV text an upload sends (exact round trip)."""
    buf = io.StringIO()
    write_native_csv(rec, buf)
    return buf.getvalue()


def bad_csv_uploads() -> dict[str, bytes]:
    """CSV bodies every upload endpoint must refuse with a 4xx and a reason, by what is wrong with them."""
    import io

    from calib.io.readers import write_native_csv
    from calib.simulator import simulate

    still_only = io.StringIO()
    rec, _ = simulate(2, noise=0.03)
    write_native_csv(rec.slice(0, 250), still_only)
    return {
        "empty": b"",
        "binary": bytes(range(256)) * 50,
        "prose": b"this is not a recording\n",
        "header only": b"t,gx,gy,gz\n",
        "short rows": b"t,gx,gy,gz\n0,1\n0.01,2\n",
        "nan": b"t,gx,gy,gz\n0,nan,0,0\n0.01,0,0,0\n0.02,0,0,0\n",
        "time backwards": b"t,gx,gy,gz\n0.02,0,0,0\n0.01,0,0,0\n0,0,0,0\n",
        "imucal without fs": b"gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n" + b"0,0,0,0,0,9.81\n" * 50,
        "no protocol": still_only.getvalue().encode(),
        "latin-1": "t,gx,gy,gz\n0,1,2,3\n\xe9\n".encode("latin-1"),
    }


def make_v1_store(store_url: str) -> None:
    """A store as gyrocal 0.1 left it: schema version 1, two calibrations, five audit entries."""
    from sqlalchemy import create_engine

    dialect = "sqlite" if store_url.startswith("sqlite") else "postgresql"
    ddl = (ROOT / "tests" / "server" / "data" / f"store_v1_{dialect}.sql").read_text()
    url = store_url.replace("postgresql://", "postgresql+psycopg://")
    eng = create_engine(url)
    rows = [
        "INSERT INTO schema_info VALUES (1, 1, '2026-01-01T00:00:00')",
        "INSERT INTO sessions (id, device_id, kind, state, method, started_at, ended_at, result, passed, decision, "
        "software_version) VALUES ('s1', 'dev-1', 'live', 'done', 'closure', '2026-01-01', '2026-01-01', "
        "'{\"k\": [1, 1, 1], \"b\": [0, 0, 0]}', true, 'accepted', '0.1.0')",
        "INSERT INTO sessions (id, device_id, kind, state, method, started_at, ended_at, result, passed, decision, "
        "software_version) VALUES ('s2', 'dev-1', 'upload', 'done', 'closure', '2026-01-02', '2026-01-02', "
        "'{\"k\": [1, 1, 1], \"b\": [0, 0, 0]}', true, 'accepted', '0.1.0')",
        *[f"INSERT INTO calibrations (device_id, session_id, k_x, k_y, k_z, b_x, b_y, b_z, result, method, software_version, "
          f"operator, computed_at, accepted_at) VALUES ('dev-1', '{sid}', 1.01, 1, 1, 0, 0, 0, '{{}}', 'closure', '0.1.0', "
          f"'alice', '2026-01-0{i}', '2026-01-0{i}')" for i, sid in ((1, "s1"), (2, "s2"))],
        *[f"INSERT INTO audit_log (at, operator, action) VALUES ('2026-01-01', 'alice', 'a{i}')" for i in range(5)],
    ]
    if dialect == "sqlite":
        raw = sqlite3.connect(store_url.removeprefix("sqlite:///"))
        raw.executescript(ddl + ";\n".join(rows) + ";")
        raw.commit()
        raw.close()
    else:
        with eng.begin() as conn:
            body = "\n".join(line for line in ddl.splitlines() if not line.startswith("--"))
            for stmt in [*body.split(";\n\n"), *rows]:
                if stmt.strip():
                    conn.connection.driver_connection.execute(stmt.rstrip().rstrip(";"))
    eng.dispose()


def kit_through_the_command_line(c: httpx.Client, members: dict[str, str], folder: Path) -> dict[str, Any]:
    """One door: the recording and the section list each wearable's session of a kit kept (``members``: device id ->
    session id), given to `gyrocal calibrate-kit --sections`; its JSON output (it must succeed)."""
    args = []
    for name, sid in members.items():
        for what, suffix in (("recording", ".csv"), ("sections", ".sections.json")):
            r = c.get(f"/sessions/{sid}/{what}")
            assert r.status_code == 200, r.text
            (folder / f"{name}{suffix}").write_bytes(r.content)
        args += [str(folder / f"{name}.csv")]
    lists = [a for name in members for a in ("--sections", str(folder / f"{name}.sections.json"))]
    out = subprocess.run([*GYROCAL, "calibrate-kit", *args, *lists, "--json"], cwd=ROOT, capture_output=True, text=True,
                         timeout=120, check=False)
    assert out.returncode == 0, out.stderr
    return dict(json.loads(out.stdout))
