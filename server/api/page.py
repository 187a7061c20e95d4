"""The wizard page at /: its files, or a placeholder when they are not installed."""

from __future__ import annotations

import re
from importlib import resources
from pathlib import Path
from typing import Any

from fastapi import FastAPI
from fastapi.responses import HTMLResponse, JSONResponse
from fastapi.staticfiles import StaticFiles
from starlette.routing import compile_path

from ..config import Settings

_PLACEHOLDER = """<!doctype html><html lang="en"><head><meta charset="utf-8"><title>gyrocal</title></head>
<body style="font-family: sans-serif; max-width: 40em; margin: 3em auto">
<h1>gyrocal calibration service</h1>
<p>The service runs. The API is described at <a href="/docs">/docs</a> (OpenAPI: <a href="/openapi.json">/openapi.json</a>);
devices are listed at <a href="/devices">/devices</a>.</p></body></html>"""


METHODS = {"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"}


class PageFiles(StaticFiles):
    """The wizard's files at /. A method the page does not take is answered 405 with the Allow header of the API
    route at that path, if any (otherwise the catch-all mount would answer every path's OPTIONS, PUT, ...)."""

    def __init__(self, app: FastAPI, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.api = app
        self._paths: list[tuple[re.Pattern[str], set[str]]] | None = None

    def _allowed(self, path: str) -> set[str]:
        """The methods of the API operations whose path template matches ``path`` (from the published schema)."""
        if self._paths is None:
            self._paths = [(compile_path(template)[0], {m.upper() for m in ops if m.upper() in METHODS})
                           for template, ops in self.api.openapi().get("paths", {}).items()]
        allowed: set[str] = set()
        for regex, methods in self._paths:
            if regex.match(path):
                allowed |= methods
        return allowed

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        if scope["type"] == "http" and scope["method"] not in ("GET", "HEAD"):
            allow = ", ".join(sorted(self._allowed(scope["path"]) or {"GET", "HEAD"}))
            await JSONResponse({"detail": f"{scope['method']} is not allowed on {scope['path']}; allowed: {allow}"},
                               status_code=405, headers={"Allow": allow})(scope, receive, send)
            return
        await super().__call__(scope, receive, send)


def mount_page(app: FastAPI, settings: Settings) -> None:
    static = settings.static_dir
    if static is None:
        static = Path(str(resources.files("webui") / "static"))  # the wizard's files, wherever gyrocal is installed
    if Path(static).is_dir() and (Path(static) / "index.html").is_file():
        app.mount("/", PageFiles(app, directory=str(static), html=True), name="webui")
        return

    @app.get("/", response_class=HTMLResponse, include_in_schema=False)
    async def index() -> str:
        return _PLACEHOLDER
