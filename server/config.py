"""The service's settings: where the store lives, limits, the guided protocol's timings and tolerances.

Every number a clinician or an administrator may ask about is here, with its unit, and documented in
docs/service.md.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from calib.apply.identity import DEFAULT_MAX_TEMPERATURE_CHANGE_C
from calib.judge.acceptance import Tolerances


def default_db_path() -> Path:
    """The SQLite file used when no --db is given: gyrocal.sqlite3 in the user's data directory."""
    from platformdirs import user_data_dir

    return Path(user_data_dir("gyrocal", appauthor=False)) / "gyrocal.sqlite3"


DEFAULT_HEADER_TIMEOUT_S = 10.0  # a browser sends its headers in one packet; 10 s covers a very slow mobile link
DEFAULT_MAX_CONNECTIONS = 1000  # event streams of every page in a ward, with room to spare (server.http_guard)

DB_URL_HELP = "the store's URL (default as for `gyrocal serve`: GYROCAL_DB, else an SQLite file in the user's data folder)"


def default_db_url() -> str:
    """GYROCAL_DB if set, else the SQLite file in the user's data directory."""
    env = os.environ.get("GYROCAL_DB")
    if env:
        return env
    return f"sqlite:///{default_db_path()}"


@dataclass(frozen=True)
class ProtocolTimings:
    """Durations of the guided protocol, in seconds of device time (they scale with --mock-speed)."""

    initial_still_s: float = 3.0  # rest before the first turn (paper Section 2.3)
    pause_s: float = 2.0  # rest after each turn (counted from when the rest began) before the next prompt
    min_rest_before_turn_s: float = 1.5  # a turn started early is still accepted after this much rest
    rest_seen_s: float = 0.5  # rest after a full turn that counts as "put down" (moving again = moved in the pause)
    settle_s: float = 1.0  # rest needed after a reconnection before the turn is asked again
    hint_after_s: float = 20.0  # no expected motion for this long -> a hint
    fail_after_s: float = 60.0  # ... and for this long -> the session fails
    max_turn_s: float = 30.0  # a turn longer than this is not a hand turn of the protocol


DEFAULT_MAX_AGE_DAYS = 30.0  # a calibration older than this is due (as imucal warns)
DEFAULT_LEASE_S = 30.0  # a gateway's hold on a wearable outlasts its last heartbeat by this long
DEFAULT_HEARTBEAT_S = 5.0  # how often a gateway says it is alive (at most: a quarter of a shorter lease)


@dataclass(frozen=True)
class CalibrationLimits:
    """How old, and how far in temperature from a recording, a calibration may be before it is warned of."""

    max_age_days: float = DEFAULT_MAX_AGE_DAYS
    max_temperature_change_c: float = DEFAULT_MAX_TEMPERATURE_CHANGE_C


@dataclass(frozen=True)
class GatewaySettings:
    """This service as one gateway of a fleet sharing one store (docs/deployment.md)."""

    name: str  # the room's gateway name, unique in the fleet
    url: str | None = None  # where other gateways' pages send a clinician to reach this one
    lease_s: float = DEFAULT_LEASE_S  # a device's lease lasts this long unless the heartbeat renews it
    heartbeat_s: float = DEFAULT_HEARTBEAT_S  # how often the gateway says it is alive, reports what it sees and renews its leases

    @property
    def silent_after_s(self) -> float:
        """A gateway whose last heartbeat is older than this is shown as silent."""
        return max(3 * self.heartbeat_s, self.lease_s)


@dataclass(frozen=True)
class Settings:
    """Everything the service needs to start."""

    db_url: str = field(default_factory=default_db_url)
    host: str = "127.0.0.1"
    port: int = 8000
    api_token: str | None = field(default_factory=lambda: os.environ.get("GYROCAL_API_TOKEN") or None)
    allowed_hosts: tuple[str, ...] = ("localhost", "127.0.0.1", "::1")  # Host names answered ("*": any); others get 400
    limits: CalibrationLimits = field(default_factory=lambda: CalibrationLimits())  # when a calibration in force is warned of
    gateway: GatewaySettings | None = None  # None: a service on its own
    pin_from: tuple[str, ...] = ("127.0.0.0/8", "::1/128")  # client networks whose sign-ins may use a PIN
    auth_reads: bool = False  # when True, reads need a token too (SSE may pass it as ?access_token=)
    max_body_bytes: int = 32 * 1024 * 1024  # uploads above this get 413
    max_upload_samples: int = 2_000_000
    max_diagnose_samples: int = 100_000  # a model check needs about 10-13 kB a sample (1.0 GB at 100 000); more get 413
    worker_memory_mb: int = 3072  # address space of each worker process (estimators, model checks); beyond: MemoryError
    anonymous_analyses_per_min: float = 6.0  # POST /diagnose without a token, per client address (burst 3)
    token_ttl_s: float = 12 * 3600.0
    method: str = "closure"  # estimator of live sessions
    # the heading a device is put back with after each turn, 1 sigma deg, where the site knows it (closure); None:
    # learned from each recording's turns about horizontal axes (calib.estimators.closure.heading)
    heading_prior_deg: float | None = None
    timings: ProtocolTimings = field(default_factory=ProtocolTimings)
    tolerances: Tolerances = field(default_factory=Tolerances)
    max_turn_attempts: int = 3  # tries per turn: a failed turn check asks for the turn again until this many (1: it ends the session)
    link_silence_s: float = 2.0  # seconds of the service's running time without data before the page says so
    reconnect_timeout_s: float = 60.0  # wall-clock seconds to get the link (or its data) back before failing
    service_late_limit_s: float = 300.0  # a session whose service did not run this long in all ends service_overloaded
    compute_timeout_s: float = 120.0  # the estimator gets this long (wall clock) for one session
    session_timeout_s: float = 900.0  # wall-clock watchdog: no live session runs longer than this
    sse_linger_s: float = 600.0  # an ended session's event stream closes after this, or at its decision
    sse_rate_hz: float = 20.0  # live angle / progress snapshots per second (state changes are never held back)
    integrity_check_s: float = 300.0  # the store's hash chains are verified this often (and at start, and on /health?verify=true)
    static_dir: Path | None = None  # the wizard page; default: webui/static if it exists
