"""What a new result is judged against, from the device's past: its accepted calibrations (for departures and the
turns' accuracy, calib.judge) and the checks its last judged result failed (for the words of a failure)."""

from __future__ import annotations

from collections.abc import Set
from typing import Any

from ..store import Store

FailedChecks = Set[tuple[str, str | None]]  # (check name, axis)


def calibration_history(store: Store, device_id: str) -> list[dict[str, Any]]:
    """The device's accepted calibrations, newest first, in the form calib.judge.judge reads."""
    return [c.model_dump() for c in store.calibrations(device_id)]


def failed_last_time(store: Store, device_id: str, limit: int = 20) -> FailedChecks:
    """The checks the device's last judged result failed: empty when it passed, or the device has none."""
    for row in store.sessions(device_id, limit):
        if not row["result"] or row["kind"] in ("verify", "watch") or row["state"] not in ("done", "failed"):
            continue
        if row["reason_code"] not in (None, "out_of_tolerance"):
            continue  # ended for another reason: not a judged result
        checks = (row["info"] or {}).get("checks") or []
        return {(str(c.get("name")), c.get("axis")) for c in checks if isinstance(c, dict) and not c.get("ok")}
    return set()
