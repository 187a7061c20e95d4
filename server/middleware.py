"""The service's own ASGI middleware: request bodies bounded before any route reads them."""

from __future__ import annotations

from typing import Any

from fastapi.responses import JSONResponse


class BodyLimit:
    """Refuses request bodies above a size with 413: by Content-Length at once, and a body sent without one
    (chunked) is read up to the limit before the route sees it, so every route answers 413 alike."""

    def __init__(self, app: Any, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def _refuse(self, scope: Any, receive: Any, send: Any, status: int, msg: str) -> None:
        await JSONResponse({"detail": msg}, status_code=status)(scope, receive, send)

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = dict(scope.get("headers") or [])
        too_big = f"the request body is larger than {self.max_bytes // (1024 * 1024)} MiB; send a shorter recording"
        length = headers.get(b"content-length")
        if length is not None:
            try:
                n = int(length)
            except ValueError:
                n = -1
            if n < 0:
                await self._refuse(scope, receive, send, 400, "the Content-Length header is not a number")
            elif n > self.max_bytes:
                await self._refuse(scope, receive, send, 413, too_big)
            else:
                await self.app(scope, receive, send)
            return
        if b"chunked" not in headers.get(b"transfer-encoding", b"").lower():
            await self.app(scope, receive, send)
            return
        body, more = bytearray(), True
        while more:
            message = await receive()
            if message["type"] != "http.request":
                return  # the client went away
            body += message.get("body", b"")
            more = message.get("more_body", False)
            if len(body) > self.max_bytes:
                await self._refuse(scope, receive, send, 413, too_big)
                return
        replayed = False

        async def replay() -> Any:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": bytes(body), "more_body": False}
            return await receive()

        await self.app(scope, replay, send)
