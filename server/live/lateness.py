"""How a guided session tells a late service or late data from a lost link: silence on the wall clock judges
nothing; the samples that come after it say whether any were lost; the time the service itself did not run is said
and left out of the wall-clock limits.

``Lateness`` is a part of ``GuidedSession`` (server.live.session); the fields and methods declared here without a
body are the session's.
"""

from __future__ import annotations

from collections.abc import Callable

from ..config import Settings
from . import guidance as say
from .codes import EndReason, State

SERVICE_LATE_REPEAT_S = 10.0  # device seconds between two warnings that the service was late


class Lateness:
    """Silence, late data and the service's own lateness, for a guided session."""

    state: State
    settings: Settings
    t_now: float
    started_mono: float
    clock: Callable[[], float]
    _link_lost_mono: float | None
    _silent_since: float | None
    _late_said_at: float
    service_late_s: float

    @property
    def finished(self) -> bool:
        raise NotImplementedError

    def fail(self, code: EndReason | str, message: str) -> None: ...

    def link_lost(self) -> None: ...

    def link_restored(self) -> None: ...

    def _warn(self, code: str, message: str, emit: bool = True) -> None: ...

    @property
    def silent(self) -> bool:
        """Whether no data has come for a while though the link says it is up (``data_silent``, until it resumes)."""
        return self._silent_since is not None and not self.finished

    def data_silent(self, silent_s: float) -> None:
        """No data for ``silent_s`` of the service's running time while the link says it is up. Nothing is
        judged from it: the data may only be late. What the samples show when they come back decides."""
        if self.finished or self._silent_since is not None or self.state in (State.COMPUTING, State.RECONNECTING, State.CONNECTING):
            return
        self._silent_since = self.clock() - silent_s
        self._warn("no_data", say.no_data(silent_s))

    def data_resumed(self, lost: int) -> None:
        """Data again after a silence: with samples missing (``lost``, from the sequence and the device's clock)
        the link was lost, and the step it interrupted is done again; complete, it was only late, and the
        session carries on where it was."""
        if self._silent_since is None:
            return
        late_s = self.clock() - self._silent_since
        self._silent_since = None
        if lost > 0:
            self.link_lost()
            self.link_restored()
        else:
            self._warn("data_resumed", say.data_resumed(late_s))

    def service_was_late(self, late_s: float) -> None:
        """The service itself did not run for ``late_s`` (a starved or stalled process): its wall-clock limits
        do not count that time, it says so, and past ``service_late_limit_s`` in all it ends the session with a
        reason of its own."""
        if self.finished or late_s <= 0:
            return
        self.service_late_s += late_s
        self.started_mono += late_s
        if self._link_lost_mono is not None:
            self._link_lost_mono += late_s
        if self._silent_since is not None:
            self._silent_since += late_s
        if self.service_late_s > self.settings.service_late_limit_s:
            self.fail(EndReason.SERVICE_OVERLOADED, say.service_overloaded(self.service_late_s))
        elif self.t_now - self._late_said_at >= SERVICE_LATE_REPEAT_S:
            self._late_said_at = self.t_now
            self._warn("service_late", say.service_late(late_s))
