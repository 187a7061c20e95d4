"""`gyrocal operator` and `gyrocal serve` on the command line, and a service that needs tokens for reads."""

from __future__ import annotations

import io
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from server_fixtures import API_TOKEN, GYROCAL, ROOT, RunningService, follow_events

from calib.cli.main import main
from server.auth import Authenticator
from server.store import Store


def test_operator_commands(tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    db = f"sqlite:///{tmp_path / 'ops.sqlite3'}"
    assert main(["operator", "--db", db, "list"]) == 0
    assert "no operators yet" in capsys.readouterr().out
    assert main(["operator", "--db", db, "add", "alice"]) == 0
    secret = capsys.readouterr().out.strip().splitlines()[-1]
    assert len(secret) >= 32
    auth = Authenticator(Store(db))
    assert auth.sign_in("alice", secret)[0]
    assert main(["operator", "--db", db, "add", "alice"]) == 2
    assert "exists already" in capsys.readouterr().err
    monkeypatch.setattr("sys.stdin", io.StringIO("chosen secret 123\n"))
    assert main(["operator", "--db", db, "add", "bob", "--secret-stdin"]) == 0
    assert "chosen secret" not in capsys.readouterr().out  # a secret given on stdin is never echoed
    assert auth.sign_in("bob", "chosen secret 123")[0]
    assert main(["operator", "--db", db, "reset", "alice"]) == 0
    new = capsys.readouterr().out.strip().splitlines()[-1]
    assert new != secret and auth.sign_in("alice", new)[0]
    assert main(["operator", "--db", db, "remove", "bob"]) == 0
    assert main(["operator", "--db", db, "list"]) == 0
    listing = capsys.readouterr().out
    assert "alice" in listing and "active" in listing and "removed" in listing
    assert main(["operator", "--db", db, "add", "api"]) == 2
    assert "reserved" in capsys.readouterr().err
    assert main(["operator", "--db", db, "add", "bad name!"]) == 2
    assert main(["operator", "--db", db, "remove", "nobody"]) == 2


def test_operator_db_after_the_action(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`gyrocal operator add NAME --db URL`, as the docs write it, acts on URL; a --db before the action still does."""
    db = f"sqlite:///{tmp_path / 'ops.sqlite3'}"
    assert main(["operator", "add", "carol", "--db", db]) == 0
    assert main(["operator", "--db", db, "add", "dave"]) == 0
    capsys.readouterr()
    assert main(["operator", "list", "--db", db]) == 0
    listing = capsys.readouterr().out
    assert "carol" in listing and "dave" in listing
    assert {o["name"] for o in Store(db).operators()} == {"carol", "dave"}



def test_once_a_command_has_ended_the_sqlite_file_alone_holds_what_it_wrote(tmp_path: Path) -> None:
    """The gyrocal command, as a shell runs it: its store's write-ahead log is folded into the file as it exits, so a
    copy of the file (a backup, a store moved to another computer) is whole."""
    db = tmp_path / "store.sqlite3"
    r = subprocess.run([*GYROCAL, "operator", "--db", f"sqlite:///{db}", "add", "carol", "--secret-stdin"], cwd=ROOT,
                       input="a long enough secret\n", capture_output=True, text=True, timeout=60, check=False)
    assert r.returncode == 0, r.stderr
    assert not (tmp_path / "store.sqlite3-wal").exists()
    copy = tmp_path / "copy" / "store.sqlite3"
    copy.parent.mkdir()
    shutil.copyfile(db, copy)
    store = Store(f"sqlite:///{copy}")
    try:
        assert [o["name"] for o in store.operators()] == ["carol"]
    finally:
        store.close()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--mock", "2", "--mock-rate", "100"], "--mock-rate must be one of"),
        (["--mock", "1", "--mock-scenario", "juggling"], "unknown --mock-scenario juggling"),
        (["--mock-speed", "0"], "--mock-speed must be a positive number"),
        (["--method", "guess"], "--method must be one of"),
        (["--max-attempts", "9"], "--max-attempts must be between 1 and 5"),
        (["--db", "nonsense"], "not a database URL"),
        (["--host", "0.0.0.0"], "add --auth-reads so reads need a token too, or --open-reads"),
        (["--worker-memory-mb", "10"], "--worker-memory-mb must be between"),
        (["--ble", "--ble-adapter", "hci0,usb1"], "name each adapter once, as BlueZ does"),
        (["--ble", "--ble-adapter", "hci0,hci0"], "name each adapter once"),
        (["--ble", "--ble-slots", "0"], "an adapter holds between 1 and 20 connections"),
        (["--ble", "--ble-time-scale", "0"], "above 0 and at most 1000 (1 for real hardware)"),
        (["--gateway", "room 3!"], "use letters, digits, '.', '_' or '-'"),
        (["--gateway", "room-3", "--lease-s", "1"], "between 5 and 3600 seconds"),
        (["--gateway-url", "http://gw:8000"], "--gateway-url needs --gateway NAME"),
        (["--gateway", "room-3", "--gateway-url", "gw3"], "give the http(s):// address"),
        (["--mock", "1", "--mock-first", "0"], "--mock-first takes the first simulated wearable's number"),
        (["--header-timeout-s", "0"], "--header-timeout-s must be between 0.5 and 600 seconds"),
        (["--max-connections", "3"], "--max-connections must be between 16 and 1000000"),
        (["--mock", "1", "--mock-kit"], "give at least two with --mock N"),
        (["--mock", "3", "--mock-kit-loose", "2"], "--mock-kit-loose names one of the kit's simulated wearables"),
        (["--mock", "3", "--mock-kit", "--mock-kit-loose-in", "pause"], "give --mock-kit-loose I too"),
        (["--mock", "3", "--mock-kit", "--mock-kit-out", "4"], "--mock-kit-out names one of the kit's simulated wearables"),
        (["--mock", "3", "--mock-kit", "--mock-kit-out", "2", "--mock-kit-loose", "2"], "it cannot slip in its slot"),
        (["--mock", "3", "--mock-kit-misalignment", "0.01"], "--mock-kit-misalignment is the largest cross-axis entry"),
        (["--mock", "3", "--mock-kit", "--mock-kit-misalignment", "0.7"], "between 0 and 0.5 (e.g. 0.01), with --mock-kit"),
        (["--mock", "3", "--mock-kit", "--mock-scenario", "hand:careful,hand:bumps"], "turned by one clinician"),
        (["--mock", "3", "--mock-kit", "--mock-scenario", "wrong_axis"], "give one hand:STYLE"),
        (["--mock", "3", "--mock-kit", "--mock-kit-drop", "2", "--mock-scenario", "hand:careful"],
         "--mock-kit-drop plays with the scripted tray clinician"),
    ],
)
def test_serve_refuses_bad_options_with_a_message(
    args: list[str], message: str, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    if "--db" not in args:
        args = [*args, "--db", f"sqlite:///{tmp_path / 's.sqlite3'}"]
    assert main(["serve", *args]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_reads_need_a_token_with_auth_reads(tmp_path: Path) -> None:
    svc = RunningService(["--auth-reads", "--mock", "1", "--mock-speed", "50", "--mock-seed", "5"],
                         f"sqlite:///{tmp_path / 's.sqlite3'}").start()
    try:
        with svc.client(token=None) as anon:
            assert anon.get("/health").json()["auth_reads"] is True
            assert anon.get("/devices").status_code == 401
            assert anon.get("/devices/mock-1/calibrations").status_code == 401
        with svc.client() as c:
            assert [d["id"] for d in c.get("/devices").json()] == ["mock-1"]
            sid = c.post("/devices/mock-1/calibrate").json()["session_id"]  # no body at all
            assert c.get(f"/sessions/{sid}").status_code == 200
        with svc.client(token=None) as anon:
            assert anon.get(f"/sessions/{sid}/events").status_code == 401
        # an EventSource cannot send headers: the token goes in the query
        events = follow_events(
            f"{svc.base}", sid, {"done", "failed", "cancelled"}, timeout_s=60, last_event_id=0, params={"access_token": API_TOKEN}
        )
        assert events[-1]["state"] == "done", {k: events[-1].get(k) for k in ("reason_code", "reason", "warnings", "lost_samples")}
    finally:
        svc.stop()


def test_the_service_process_starts_without_the_estimators_heavy_numerics() -> None:
    """scipy loads in the compute workers, where the estimators run, and in the simulated wearables; the service's own
    process (live detection, the store, the API) starts without it, so a gateway comes up and restarts quickly."""
    code = "import sys, server.main; print(sorted({m.split('.')[0] for m in sys.modules} & {'scipy', 'matplotlib'}))"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_when_a_simulated_wearable_slips_is_offered_as_the_simulator_knows_it() -> None:
    # the command line writes the choices out (importing the simulator would load scipy at each start): they must stay
    # the simulator's
    from calib.cli.main import build_parser
    from calib.simulator.kit import SLIP_WHEN

    sub = next(a for a in build_parser()._actions if a.choices and "serve" in a.choices).choices
    offered = {next(a.choices for a in sub[cmd]._actions if a.dest == dest)
               for cmd, dest in (("serve", "mock_kit_loose_in"), ("simulate-kit", "slip_in"))}
    assert offered == {SLIP_WHEN}
