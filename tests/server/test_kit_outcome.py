"""What a kit's wearables are told when the kit cannot be calibrated for a reason of the service's own: each session
ends saying the service was overloaded (its reason code too), never the recording or the hand, and says what to do
once."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

from calib.simulator import simulate
from calib.stages.detector import detect_stages
from server.config import Settings
from server.live import guidance as say
from server.live.codes import EndReason
from server.live.kit_session import KitSession
from server.live.session import GuidedSession


@dataclass
class _Wearable:
    """A kit's member as the kit sees it: the real guided session of a wearable the test names."""

    device: Any
    machine: GuidedSession
    kit: Any = field(default=None)

    def cancel(self, reason: str = "Cancelled by the operator.") -> bool:
        return False


def test_a_kit_whose_calibration_runs_out_of_time_says_the_service_was_overloaded() -> None:
    names = ["mock-1", "mock-2"]
    members = [_Wearable(SimpleNamespace(id=n), GuidedSession(f"s{i}", n, Settings(db_url="sqlite://")))
               for i, n in enumerate(names)]
    limit_s = 0.001  # the estimator (run in a thread: no pool) cannot finish in a millisecond, as on a starved machine
    kit = KitSession("k" * 32, members, None, limit_s, "alice")
    recordings = [simulate(seed)[0] for seed in (1, 2)]

    async def both() -> list[Any]:
        return await asyncio.gather(*(kit.outcome_for(m, rec, detect_stages(rec)) for m, rec in zip(members, recordings, strict=True)))

    outcomes = asyncio.run(both())
    said = say.compute_timeout(limit_s, "the kit's calibration")
    assert [(o.result, o.end, o.refusal) for o in outcomes] == [(None, EndReason.SERVICE_OVERLOADED, said)] * 2
    assert "the service is overloaded, not the device nor the way it was turned" in said
    assert said.count("Start a new calibration") == 1
    assert kit.outcome is not None and kit.outcome.refusal == said
