"""The house's structure, measured: import cycles between gyrocal's modules, the layering rules
(calib imports no other package of ours; the server never imports mock_device; the mock device only the
protocol and calib), no module importing another's private (underscore) names, and every module's size,
largest first, and that docs/architecture.md names every module. Exit 1 on a cycle, a layering breach, a borrowed
private name, a module over MAX_LINES or one the architecture does not name.

Run: python scripts/check_structure.py [--sizes N]   (make test runs it)
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

import networkx as nx

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("calib", "server", "mock_device", "wearable_protocol", "webui")
MAX_LINES = 400  # a module longer than this holds more than one job: split it
# package -> the packages of ours it may import
ALLOWED = {
    "calib": set(),
    "wearable_protocol": set(),
    "webui": set(),
    "server": {"calib", "wearable_protocol", "webui"},
    "mock_device": {"calib", "wearable_protocol"},
}


def modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            name = ".".join(path.relative_to(ROOT).with_suffix("").parts)
            out[name.removesuffix(".__init__")] = path
    return out


def imports(name: str, path: Path, known: dict[str, Path]) -> set[str]:
    """The gyrocal modules ``name`` imports (relative imports resolved; a package import counts as its __init__)."""
    is_pkg = path.name == "__init__.py"
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = name.split(".")
            if node.level:
                base = base[: len(base) - node.level + (1 if is_pkg else 0)]
                stem = ".".join(base + ([node.module] if node.module else []))
            else:
                stem = node.module or ""
            targets = [stem] + [f"{stem}.{a.name}" for a in node.names]
        for t in targets:
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t and t != name and not name.startswith(t + "."):
                found.add(t)
    return found


def borrowed_private_names(name: str, path: Path, known: dict[str, Path]) -> list[str]:
    """``from other import _name`` in module ``name``: another module's private name taken for its own use."""
    is_pkg = path.name == "__init__.py"
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if not isinstance(node, ast.ImportFrom):
            continue
        if node.level:
            base = name.split(".")
            base = base[: len(base) - node.level + (1 if is_pkg else 0)]
            source = ".".join(base + ([node.module] if node.module else []))
        else:
            source = node.module or ""
        if source.split(".")[0] not in PACKAGES or source == name:
            continue
        out += [f"{name} imports {a.name} from {source}" for a in node.names if a.name.startswith("_") and not a.name.startswith("__")]
    return out


def unnamed_in_architecture(known: dict[str, Path]) -> list[str]:
    """The modules docs/architecture.md does not name (package __init__ files and migrations aside)."""
    import re

    doc = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    return sorted(name for name, path in known.items()
                  if path.name != "__init__.py" and "migrations" not in path.parts
                  and not re.search(rf"\b{re.escape(path.stem)}\b", doc))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, default=15, help="list this many of the largest modules")
    args = ap.parse_args()
    known = modules()
    graph = nx.DiGraph()
    for name, path in known.items():
        graph.add_node(name)
        for target in imports(name, path, known):
            graph.add_edge(name, target)
    failures = []
    cycles = [sorted(c) for c in nx.strongly_connected_components(graph) if len(c) > 1]
    for c in cycles:
        failures.append("import cycle: " + " <-> ".join(c))
    for a, b in graph.edges:
        pa, pb = a.split(".")[0], b.split(".")[0]
        if pa != pb and pb not in ALLOWED[pa]:
            failures.append(f"layering: {a} imports {b} ({pa} may import only {', '.join(sorted(ALLOWED[pa])) or 'none of ours'})")
    for name, path in known.items():
        failures += [f"private name borrowed: {b}" for b in borrowed_private_names(name, path, known)]
    failures += [f"docs/architecture.md does not name the module {name}" for name in unnamed_in_architecture(known)]
    sizes = sorted(((sum(1 for _ in p.open()), n) for n, p in known.items()), reverse=True)
    failures += [f"{name} has {lines} lines (at most {MAX_LINES})" for lines, name in sizes if lines > MAX_LINES]
    print(f"{len(known)} modules, {graph.number_of_edges()} imports between them, {len(cycles)} cycles")
    print(f"largest modules (over {MAX_LINES} lines marked *):")
    for lines, name in sizes[: args.sizes]:
        print(f"  {'*' if lines > MAX_LINES else ' '} {lines:5d}  {name}")
    for f in failures:
        print(f"FAIL {f}", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
