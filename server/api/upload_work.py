"""An uploaded recording's work in the service's worker pool (correct it, measure a verification turn in it, watch a
calibration on it), with what can go wrong answered as the person who sent it reads it: too large (413), too slow
(503), or the recording at fault (4xx, ``recording_problem``)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any, TypeVar

from ..deps import problem, recording_problem
from ..service import Service
from ..workers.compute import TooManySamples

T = TypeVar("T")


async def upload_work(svc: Service, work: Callable[..., T], *args: Any, doing: str, too_slow: str,
                      refused: tuple[type[Exception], ...] = ()) -> T:
    """``work(*args)`` in the worker pool within the service's compute time limit. ``doing`` ("corrected", "watched"…)
    names it in a recording's problem; ``too_slow`` is the 503's words; ``refused``: errors of the work's own that say
    what the recording lacks, answered 400 with their message."""
    try:
        return await asyncio.wait_for(svc.pool.run(work, *args), timeout=svc.settings.compute_timeout_s)
    except refused as exc:
        raise problem(400, str(exc)) from None
    except TooManySamples as exc:
        raise problem(413, str(exc)) from None
    except TimeoutError:
        raise problem(503, too_slow) from None
    except Exception as exc:  # calib's errors and whatever else the parser trips on
        raise recording_problem(exc, doing, upload=True) from None
