"""Every icon the page names is one it draws: ``icon(name)`` falls back to the info glyph for a name it does not know,
so a misspelt name would show an "i" in a circle where an action's picture belongs, and no browser would complain."""

from __future__ import annotations

import re
from pathlib import Path

STATIC = Path(__file__).resolve().parents[2] / "webui" / "static"


def test_every_icon_named_in_the_page_is_drawn() -> None:
    figures = (STATIC / "figures.js").read_text()
    table = figures[figures.index("const ICON_PATHS = {"):]
    drawn = set(re.findall(r"^\s+([a-z]+): \[", table[:table.index("\n};")], flags=re.M))
    assert {"info", "warn", "check", "upload", "fleet"} <= drawn, drawn
    named: dict[str, set[str]] = {}
    for js in STATIC.glob("*.js"):
        text = js.read_text()
        # icon("name"), icon(a ? "one" : "other") and the icon: / glyph: fields whose names are passed to icon()
        calls = re.findall(r"\bicon\(([^()]*)\)", text)
        # (the words compared with, in icon(state === "done" ? "check" : ...), are no icons)
        words = [w for call in calls for w in re.findall(r'"([a-z]+)"', re.sub(r'[=!]==?\s*"[a-z]+"', "", call))]
        words += re.findall(r'\b(?:icon|glyph): "([a-z]+)"', text)
        for word in words:
            named.setdefault(word, set()).add(js.name)
    assert len(named) >= 20, named
    unknown = {w: sorted(files) for w, files in named.items() if w not in drawn}
    assert unknown == {}, unknown
