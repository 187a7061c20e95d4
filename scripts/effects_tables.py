"""Write the effect catalogue's tables into the documentation from the effects' specs (calib.effects).

Usage: ``python scripts/effects_tables.py`` rewrites the tables in place; ``--check`` only reports the
files whose tables are out of date (exit status 1), as the test suite does.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from calib.effects.tables import TABLES  # noqa: E402

DOCS = (ROOT / "docs" / "effects.md", ROOT / "docs" / "diagnosis.md")
BLOCK = re.compile(r"(<!-- effects-table: (\w+) -->\n)(.*?)(<!-- /effects-table -->)", re.S)


def render(text: str) -> str:
    """``text`` with every marked table rewritten from the specs."""

    def table(m: re.Match[str]) -> str:
        name = m.group(2)
        if name not in TABLES:
            raise SystemExit(f"unknown effects table {name!r}; known: {', '.join(TABLES)}")
        return f"{m.group(1)}{TABLES[name]()}\n{m.group(4)}"

    return BLOCK.sub(table, text)


def stale() -> list[Path]:
    """The documentation files whose tables differ from what the specs give."""
    return [p for p in DOCS if render(p.read_text()) != p.read_text()]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="report out-of-date files instead of rewriting them")
    args = ap.parse_args()
    if args.check:
        out = stale()
        for p in out:
            print(f"{p.relative_to(ROOT)}: the effects tables are out of date; run python scripts/effects_tables.py")
        return 1 if out else 0
    for p in DOCS:
        p.write_text(render(p.read_text()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
