"""The store's errors: each message says what is wrong and what to do."""

from __future__ import annotations

from datetime import datetime


class StoreError(Exception):
    """The store could not be opened or written; the message says why."""


class NotFound(StoreError):
    """No such session (or other row) in the store."""


class DecisionConflict(StoreError):
    """A session was accepted or discarded already (by someone else, or by a request a moment earlier)."""

    def __init__(self, session_id: str, decision: str, by: str | None, at: datetime | None) -> None:
        who = f" by {by}" if by else ""
        when = f" at {at.isoformat(timespec='seconds')}" if at else ""
        self.decided = f"{decision} already{who}{when}"  # "accepted already by alice at ...", for a sentence of its own
        super().__init__(f"session {session_id} was {self.decided}; nothing was changed")
        self.session_id = session_id
        self.decision = decision
        self.by = by
        self.at = at


class NotAcceptable(StoreError):
    """A session that cannot become a calibration (not done, out of tolerance, no sensor identity)."""


class StoreFull(StoreError):
    """The disk (or the database's space) holding the store is full: nothing more can be written until space is freed."""

    def __init__(self, where: str, detail: str) -> None:
        super().__init__(f"the disk holding the store ({where}) is full ({detail}): free space there")
        self.where = where


def store_trouble(exc: BaseException) -> str:
    """Why the store did not take a write, in an operator's words: a full disk named as such, anything else as the
    store being unavailable (its class, for the log's reader)."""
    if isinstance(exc, StoreFull):
        return str(exc)
    return f"the store is unavailable ({type(exc).__name__})"


def is_disk_full(exc: BaseException) -> bool:
    """Whether a database error means the disk or the database's space is full (SQLite's SQLITE_FULL, PostgreSQL's
    disk_full 53100, or the operating system's ENOSPC as either reports it)."""
    orig = getattr(exc, "orig", None) or exc
    if getattr(orig, "sqlite_errorcode", None) == 13 or getattr(orig, "sqlstate", None) == "53100":
        return True
    text = str(orig).lower()
    return "database or disk is full" in text or "no space left on device" in text
