"""Fixtures for the BLE tests: a private dbus-daemon per test and the simulated BlueZ on it.

Registered as a plugin by tests/conftest.py: the fixtures need no import.
bleak reads DBUS_SYSTEM_BUS_ADDRESS when it connects and keeps one BlueZ manager per event loop;
every test has its own loop, so every test gets a fresh bus and a fresh bleak manager.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from mock_device.bluez import BlueZThread, PrivateBus, write_bluetoothctl_shim


@pytest.fixture
def dbus_bus(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[PrivateBus]:
    """A private dbus-daemon; DBUS_SYSTEM_BUS_ADDRESS points at it and a bluetoothctl shim is on PATH."""
    if shutil.which("dbus-daemon") is None:
        pytest.fail("dbus-daemon is missing: install the Debian package 'dbus' (make test does it via "
                    "scripts/install-system-deps.sh)")
    bus = PrivateBus(tmp_path / "dbus")
    address = bus.start()
    monkeypatch.setenv("DBUS_SYSTEM_BUS_ADDRESS", address)
    monkeypatch.setenv("PATH", f"{write_bluetoothctl_shim(tmp_path / 'bin')}{os.pathsep}{os.environ['PATH']}")
    yield bus
    bus.stop()


@pytest.fixture
def simulated_bluez(dbus_bus: PrivateBus) -> Iterator[Callable[..., BlueZThread]]:
    """Factory: ``simulated_bluez([peripheral, ...], **options)`` serves them on the private bus from a
    background thread (use ``.call(fn, *args)`` to touch a peripheral). Stopped after the test."""
    started: list[BlueZThread] = []

    def start(peripherals: list[Any], **options: Any) -> BlueZThread:
        assert dbus_bus.address is not None
        th = BlueZThread(dbus_bus.address, peripherals, **options).start()
        started.append(th)
        return th

    yield start
    for th in started:
        th.stop()
