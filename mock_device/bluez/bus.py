"""A private D-Bus: its own dbus-daemon, ended with the process that started it, and the bluetoothctl stand-in
bleak asks for its version."""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

from calib.errors import GyrocalError

from .names import BLUEZ_VERSION

_BUS_CONFIG = """<!DOCTYPE busconfig PUBLIC "-//freedesktop//DTD D-Bus Bus Configuration 1.0//EN"
 "http://www.freedesktop.org/standards/dbus/1.0/busconfig.dtd">
<busconfig>
  <type>session</type>
  <listen>unix:path={socket}</listen>
  <auth>EXTERNAL</auth>
  <policy context="default">
    <allow send_destination="*" eavesdrop="true"/>
    <allow eavesdrop="true"/>
    <allow own="*"/>
  </policy>
  <limit name="max_incoming_bytes">1000000000</limit>
  <limit name="max_outgoing_bytes">1000000000</limit>
  <limit name="max_message_size">1000000000</limit>
</busconfig>
"""


class BusUnavailable(GyrocalError):
    """The private D-Bus daemon could not be started."""


def _die_with_parent() -> None:
    """In the daemon child: get SIGTERM when the process that started it dies (Linux prctl)."""
    with contextlib.suppress(Exception):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


class PrivateBus:
    """A ``dbus-daemon`` on a private Unix socket, started and stopped by us.

    Use as a context manager or call :meth:`start` / :meth:`stop`. ``address`` is what to put in
    ``DBUS_SYSTEM_BUS_ADDRESS`` for bleak.
    """

    def __init__(self, workdir: str | os.PathLike[str] | None = None) -> None:
        self._own_dir = workdir is None
        self.workdir = Path(workdir) if workdir else None
        self.address: str | None = None
        self._proc: subprocess.Popen[bytes] | None = None

    def start(self) -> str:
        """Start the daemon; returns its address."""
        exe = shutil.which("dbus-daemon")
        if exe is None:
            raise BusUnavailable(
                "dbus-daemon is not installed: install the Debian package 'dbus' "
                "(sudo apt-get install dbus, or run scripts/install-system-deps.sh)"
            )
        if self.workdir is None:
            self.workdir = Path(tempfile.mkdtemp(prefix="gyrocal-dbus-"))
        self.workdir.mkdir(parents=True, exist_ok=True)
        config = self.workdir / "bus.conf"
        config.write_text(_BUS_CONFIG.format(socket=self.workdir / "system_bus_socket"))
        self._proc = subprocess.Popen(
            [exe, f"--config-file={config}", "--nofork", "--nopidfile", "--print-address=1"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
            preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None,
        )
        atexit.register(self.stop)
        assert self._proc.stdout is not None
        line = self._proc.stdout.readline().decode().strip()
        if not line:
            err = self._proc.stderr.read().decode() if self._proc.stderr else ""
            self.stop()
            raise BusUnavailable(f"dbus-daemon did not start: {err.strip() or 'no address printed'}")
        self.address = line
        return line

    def stop(self) -> None:
        """Stop the daemon and remove its socket and config (idempotent)."""
        proc, self._proc = self._proc, None
        if proc is not None and proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if proc is not None:
            for stream in (proc.stdout, proc.stderr):
                if stream is not None:
                    stream.close()
        if self._own_dir and self.workdir is not None:
            shutil.rmtree(self.workdir, ignore_errors=True)
            self.workdir = None
        self.address = None

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    def __enter__(self) -> PrivateBus:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def write_bluetoothctl_shim(directory: str | os.PathLike[str]) -> Path:
    """Write an executable ``bluetoothctl`` answering ``--version`` with 5.72 (bleak's version check);
    put ``directory`` first on PATH. Returns the directory."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    exe = d / "bluetoothctl"
    exe.write_text(f"#!/bin/sh\necho 'bluetoothctl: {BLUEZ_VERSION}'\n")
    exe.chmod(0o755)
    return d
