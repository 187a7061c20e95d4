"""Session churn leaves nothing behind: an ended session the service forgets is freed at once (no reference cycle
waits for the garbage collector with its sample buffers), so memory stops growing at the finished sessions it keeps."""

from __future__ import annotations

import asyncio
import gc
from pathlib import Path

import httpx
import pytest

TOKEN = "memory-churn-token"


def test_forgotten_sessions_are_freed_without_the_garbage_collector(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import server.service
    from server.config import Settings
    from server.devices import DeviceManager, load_simulators
    from server.live.runner import LiveSession
    from server.live.session import GuidedSession
    from server.main import create_app
    from server.service import Service

    monkeypatch.setattr(server.service, "KEEP_FINISHED", 5)  # forget sessions early, so a short churn forgets many
    settings = Settings(db_url=f"sqlite:///{tmp_path / 'store.sqlite3'}", api_token=TOKEN)
    devices = DeviceManager()
    devices.add_mocks(load_simulators(), 2, speed=5.0, seed=3)
    svc = Service(settings, devices=devices)
    app = create_app(settings, svc)

    async def churn() -> tuple[int, int, str]:
        async with app.router.lifespan_context(app):
            async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://localhost",
                                         headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30) as c:
                done, churned = 0, set()
                gc.collect()
                gc.disable()
                gc.set_debug(gc.DEBUG_SAVEALL)  # what only the collector could free is kept in gc.garbage instead
                try:
                    while done < 40:
                        r = await c.post(f"/devices/mock-{done % 2 + 1}/calibrate", json={})
                        if r.status_code != 202:
                            await asyncio.sleep(0.02)
                            continue
                        churned.add(r.json()["session_id"])
                        await c.post(f"/sessions/{r.json()['session_id']}/cancel")
                        done += 1
                    await asyncio.sleep(0.5)
                    kept = len(svc.sessions)
                    gc.collect()
                    # only this churn's sessions: an earlier test in this process may leave cyclic sessions of its own
                    cyclic = [o for o in gc.garbage if _session_id(o, GuidedSession, LiveSession) in churned]
                    held_by = _held_by(cyclic[0], gc.garbage) if cyclic else ""
                finally:
                    gc.set_debug(0)
                    gc.garbage.clear()
                    gc.enable()
                return kept, len(cyclic), held_by

    kept, cyclic, held_by = asyncio.run(churn())
    assert kept <= 5 + 2  # the finished sessions kept, and any still ending
    assert cyclic == 0, f"{cyclic} forgotten sessions were only freeable by the garbage collector; the first held by: {held_by}"


def _session_id(obj: object, guided: type, live: type) -> str | None:
    """The id of the guided session ``obj`` is or runs, or None if it is neither."""
    if isinstance(obj, live):
        obj = obj.machine  # type: ignore[attr-defined]
    return obj.id if isinstance(obj, guided) else None  # type: ignore[attr-defined]


def _held_by(obj: object, garbage: list[object], depth: int = 6) -> str:
    """What holds ``obj`` among the garbage, breadth first (types, and each frame's function and line): the cycle to
    break, named in the failure."""
    import types

    ids = {id(o) for o in garbage}
    seen, frontier, lines = {id(obj)}, [obj], []
    for level in range(depth):
        nxt = []
        for o in frontier:
            for r in gc.get_referrers(o):
                if id(r) in ids and id(r) not in seen:
                    seen.add(id(r))
                    nxt.append(r)
                    what = (f"frame {r.f_code.co_name} ({r.f_code.co_filename.rsplit('/', 1)[-1]}:{r.f_lineno})"
                            if isinstance(r, types.FrameType) else type(r).__name__)
                    lines.append(f"{'  ' * level}{what}")
        frontier = nxt[:12]
    return "\n".join(lines[:60]) or "nothing in the garbage"
