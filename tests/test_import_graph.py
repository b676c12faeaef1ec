"""The package's import graph, read from the source: no cycle between probmap's packages."""

from __future__ import annotations

import ast
from pathlib import Path

import probmap

SRC = Path(probmap.__file__).resolve().parent


def _imported_modules(path: Path) -> set[str]:
    """Every ``probmap.*`` module a file imports, at the top or inside a function."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        found.update(n for n in names if n.startswith("probmap."))
    return found


def _top(part: str) -> str:
    return part[:-3] if part.endswith(".py") else part


def package_graph() -> dict[str, set[str]]:
    """``{package: packages it imports}`` over probmap's top-level packages and modules."""
    graph: dict[str, set[str]] = {}
    for path in SRC.rglob("*.py"):
        here = _top(path.relative_to(SRC).parts[0])
        targets = {m.split(".")[1] for m in _imported_modules(path)}
        graph.setdefault(here, set()).update(targets - {here})
    return graph


def _cycle_through(graph: dict[str, set[str]], start: str) -> list[str] | None:
    """A path start -> ... -> start, or None."""
    stack = [(start, [start])]
    seen: set[str] = set()
    while stack:
        node, path = stack.pop()
        for nxt in sorted(graph.get(node, ())):
            if nxt == start:
                return [*path, start]
            if nxt not in seen:
                seen.add(nxt)
                stack.append((nxt, [*path, nxt]))
    return None


def test_graph_is_read():
    graph = package_graph()
    assert "grid" in graph["slam"]  # known edges, so an empty graph cannot pass
    assert "geometry" in graph["datasets"]
    assert "datasets" in graph["pipelines"] and "metrics" in graph["pipelines"]


def test_no_cycle_between_packages():
    graph = package_graph()
    cycles = [c for p in sorted(graph) if (c := _cycle_through(graph, p))]
    assert not cycles, "package import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_datasets_do_not_import_metrics():
    assert "metrics" not in package_graph()["datasets"]


def test_map_file_modules_do_not_import_datasets():
    for name in ("io.py", "semantic_io.py"):
        mods = _imported_modules(SRC / "grid" / name)
        assert not any(m.startswith("probmap.datasets") for m in mods), (name, mods)
