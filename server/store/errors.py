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
        super().__init__(f"session {session_id} was {decision} already{who}{when}; nothing was changed")
        self.session_id = session_id
        self.decision = decision
        self.by = by
        self.at = at


class NotAcceptable(StoreError):
    """A session that cannot become a calibration (not done, out of tolerance, no sensor identity)."""
