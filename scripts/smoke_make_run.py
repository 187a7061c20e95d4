"""The README's first command as a newcomer runs it: `make run` in a fresh copy of the repository (its own
virtualenv, with only what `make run` installs), then a guided session on mock-1 through the REST API, then SIGTERM.

Exits 0 when the service started, printed its URL and the sign-in secret, the session ended `done`, and the service
stopped cleanly; otherwise 1, with what went wrong and the service's output. Standard library only: it must run
before anything is installed. Usage: python3 scripts/smoke_make_run.py [--keep]
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
START_S = 600.0  # a fresh virtualenv installs everything first
SESSION_S = 180.0  # the careful simulated clinician takes about half a minute
STOP_S = 20.0
END_STATES = ("done", "failed", "cancelled")


class SmokeFailure(Exception):
    """What a user running `make run` would have met."""


def fresh_copy(dest: Path) -> None:
    """The files a clone holds (tracked, and new ones git does not ignore), without anything built or installed."""
    names = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT, check=True,
                           capture_output=True).stdout.decode().split("\0")
    for name in filter(None, names):
        src = ROOT / name
        if src.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name)


def request(method: str, url: str, body: dict | None = None, token: str | None = None) -> tuple[int, dict | str]:
    data = json.dumps(body).encode() if body is not None else None
    req = urllib.request.Request(url, data=data, method=method)
    if data is not None:
        req.add_header("Content-Type", "application/json")
    if token:
        req.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            raw = r.read().decode()
            status = r.status
    except urllib.error.HTTPError as exc:
        raw, status = exc.read().decode(), exc.code
    except (urllib.error.URLError, OSError) as exc:  # refused, reset, timed out: the user's browser would fail too
        raise SmokeFailure(f"{method} {url} did not answer: {getattr(exc, 'reason', exc)}") from None
    try:
        return status, json.loads(raw)
    except ValueError:
        return status, raw


class Output:
    """The lines `make run` printed so far, read without blocking."""

    def __init__(self, proc: subprocess.Popen[bytes]) -> None:
        self.proc = proc
        self.lines: list[str] = []
        assert proc.stdout is not None
        os.set_blocking(proc.stdout.fileno(), False)
        self._rest = b""

    def poll(self) -> None:
        assert self.proc.stdout is not None
        chunk = self.proc.stdout.read() or b""
        *full, self._rest = (self._rest + chunk).split(b"\n")
        self.lines += [line.decode(errors="replace") for line in full]

    def find(self, pattern: str) -> re.Match[str] | None:
        for line in self.lines:
            m = re.search(pattern, line)
            if m:
                return m
        return None

    def text(self) -> str:
        self.poll()
        return "\n".join(self.lines + [self._rest.decode(errors="replace")])


def wait_for_start(out: Output) -> tuple[str, str]:
    deadline = time.monotonic() + START_S
    while time.monotonic() < deadline:
        out.poll()
        url, secret = out.find(r"open the wizard at (http://\S+?/) "), out.find(r"sign in as operator 'demo' with the secret (\S+)")
        if url and secret:
            return url.group(1), secret.group(1)
        if out.proc.poll() is not None:
            raise SmokeFailure(f"`make run` exited with {out.proc.returncode} before the service started")
        time.sleep(0.5)
    raise SmokeFailure(f"`make run` printed no wizard URL and sign-in secret within {START_S:g} s")


def run_session(base: str, secret: str) -> dict:
    status, page = request("GET", base)
    if status != 200 or "<html" not in str(page).lower():
        raise SmokeFailure(f"the wizard page at {base} answered {status}")
    status, login = request("POST", base + "auth/login", {"operator": "demo", "secret": secret})
    if status != 200 or not isinstance(login, dict):
        raise SmokeFailure(f"signing in as demo with the printed secret answered {status}: {login}")
    status, started = request("POST", base + "devices/mock-1/calibrate", token=login["token"])
    if status != 202 or not isinstance(started, dict):
        raise SmokeFailure(f"POST /devices/mock-1/calibrate answered {status}: {started}")
    deadline = time.monotonic() + SESSION_S
    while time.monotonic() < deadline:
        status, snap = request("GET", base + f"sessions/{started['session_id']}")
        if status == 200 and isinstance(snap, dict) and snap.get("state") in END_STATES:
            if snap["state"] != "done":
                raise SmokeFailure(f"the guided session on mock-1 ended {snap['state']}: {snap.get('reason')}")
            return snap
        time.sleep(1.0)
    raise SmokeFailure(f"the guided session on mock-1 did not end within {SESSION_S:g} s")


def service_pids(make_pid: int) -> list[int]:
    """The processes `make run` started (the service), found through /proc."""
    found, todo = [], [make_pid]
    while todo:
        pid = todo.pop()
        try:
            children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
        except OSError:
            continue
        found += [int(c) for c in children]
        todo += [int(c) for c in children]
    return found


def stop(out: Output) -> None:
    pids = service_pids(out.proc.pid)
    if not pids:
        raise SmokeFailure("`make run` has no service process to stop")
    for pid in pids:
        os.kill(pid, signal.SIGTERM)
    try:
        code = out.proc.wait(timeout=STOP_S)
    except subprocess.TimeoutExpired:
        raise SmokeFailure(f"the service did not stop within {STOP_S:g} s of SIGTERM") from None
    text = out.text()
    if code != 0:
        raise SmokeFailure(f"after SIGTERM `make run` exited with {code}, not 0")
    if "Traceback" in text:
        raise SmokeFailure("the service printed a traceback")
    if "Application shutdown complete" not in text:
        raise SmokeFailure("the service did not say it shut down gracefully")


def main() -> int:
    keep = "--keep" in sys.argv[1:]
    work = Path(tempfile.mkdtemp(prefix="gyrocal-make-run-"))
    clone = work / "gyrocal"
    fresh_copy(clone)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("VIRTUAL_ENV", "GYROCAL_"))}
    env["XDG_DATA_HOME"] = str(work / "data")  # the embedded store goes to the user's data folder: a fresh one
    proc = subprocess.Popen(["make", "run"], cwd=clone, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            start_new_session=True)
    out = Output(proc)
    t0 = time.monotonic()
    try:
        base, secret = wait_for_start(out)
        started = time.monotonic() - t0
        snap = run_session(base, secret)
        stop(out)
    except SmokeFailure as exc:
        print(f"smoke test of `make run` FAILED: {exc}\n--- what `make run` printed ---\n{out.text()}", file=sys.stderr)
        return 1
    finally:
        if proc.poll() is None:  # whatever happened, leave no service behind (it would hold port 8000)
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        if not keep:
            shutil.rmtree(work, ignore_errors=True)
    print(f"make run: the service started in {started:.0f} s (a fresh virtualenv), printed {base} and the sign-in secret; "
          f"a guided session on mock-1 ended done ({snap['samples']} samples); SIGTERM stopped it cleanly")
    return 0


if __name__ == "__main__":
    sys.exit(main())
