"""The package's import graph, read from the source: no cycle between probmap's packages, no
cycle between modules, and the layer rule: the core packages import none of ``datasets``,
``pipelines``, ``cli`` and ``viz`` (docs/architecture.md)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import probmap

SRC = Path(probmap.__file__).resolve().parent


def _module_of(path: Path) -> str:
    """``probmap.grid.fit`` for ``.../probmap/grid/fit.py`` (``probmap.grid`` for its __init__)."""
    parts = path.relative_to(SRC.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imported_modules(path: Path, source: str | None = None) -> set[str]:
    """Every ``probmap.*`` module a file imports, at the top or inside a function.

    Relative imports are resolved against the file's package, and ``from probmap import x`` counts
    as an import of ``probmap.x`` (a subpackage or a name of ``probmap`` itself).
    """
    text = path.read_text(encoding="utf-8") if source is None else source
    here = _module_of(path).split(".")
    package = here if path.name == "__init__.py" else here[:-1]
    found: set[str] = set()
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                module = ".".join([*base, *([node.module] if node.module else [])])
            else:
                module = node.module or ""
            names = [module] if module != "probmap" else []
            names += [
                f"{module}.{a.name}" for a in node.names if module == "probmap" or not node.module
            ]
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


# ----------------------------------------------------------------- the layer rule
#: The core: algorithms on arrays. (``mapping`` and ``sim`` are in the target layout of issue 19;
#: they are checked as soon as they exist.)
CORE = ("geometry", "grid", "models", "mapping", "filters", "slam", "sim")
#: What the core must not import: readers of files, pipelines, the command line, plotting.
UPPER = ("datasets", "pipelines", "cli", "viz")


def _core_files() -> list[Path]:
    return [p for pkg in CORE if (SRC / pkg).is_dir() for p in sorted((SRC / pkg).rglob("*.py"))]


def _shim_targets(tree: ast.AST) -> set[int]:
    """``id`` of every string constant inside a call to ``probmap._deprecation.moved`` (a
    one-release shim: it names a new home as a string and imports it only on lookup)."""
    ids: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "moved":
            ids.update(id(c) for c in ast.walk(node) if isinstance(c, ast.Constant))
    return ids


def layer_violations(path: Path, source: str | None = None) -> list[str]:
    """Why the core file ``path`` breaks the layer rule (empty when it keeps it).

    Two kinds: an ``import`` (anywhere in the file, at the top or inside a function) of an upper
    package, and a string naming an upper module (``importlib.import_module("probmap.cli...")``,
    ``__import__``) outside a deprecation shim's ``moved(...)`` call.
    """
    text = path.read_text(encoding="utf-8") if source is None else source
    tree = ast.parse(text)
    bad = [
        f"imports {m}" for m in sorted(_imported_modules(path, text)) if m.split(".")[1] in UPPER
    ]
    shims = _shim_targets(tree)
    prefixes = tuple(f"probmap.{u}" for u in UPPER)
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Constant)
            and isinstance(node.value, str)
            and node.value.startswith(prefixes)
            and node.value.split(".")[1] in UPPER  # probmap.cli, not probmap.climb
            and " " not in node.value  # a module name, not prose in a docstring
            and id(node) not in shims
        ):
            bad.append(f"names {node.value!r} (line {node.lineno}) outside a moved() shim")
    return bad


def test_core_imports_no_datasets_pipelines_cli_or_viz():
    files = _core_files()
    assert len(files) > 40 and {"grid", "slam", "filters"} <= {p.parts[-2] for p in files}
    bad = {str(p.relative_to(SRC)): v for p in files if (v := layer_violations(p))}
    assert not bad, "the core reaches up a layer: " + "; ".join(f"{k}: {v}" for k, v in bad.items())


def test_layer_rule_catches_every_form(tmp_path):
    """The checker itself: it sees function-level, relative and ``from probmap import`` imports
    and import_module strings, and lets a ``moved()`` shim through."""
    path = SRC / "grid" / "example.py"  # never written: only names the module for resolution
    cases = {
        "from probmap.datasets.carmen import load_scans": 1,
        "def f():\n    import probmap.viz.slam\n": 1,
        "from ..pipelines import grid_slam": 1,
        "from .. import cli": 1,
        "from probmap import datasets": 1,
        "import importlib\nimportlib.import_module('probmap.pipelines.fit')": 1,
        "from probmap.grid.spec import GridSpec\nfrom probmap import errors": 0,
        "__getattr__ = moved(__name__, {'fit_log': 'probmap.pipelines.fit'})": 0,
        '"""See probmap.pipelines.fit for the log reader."""': 0,
    }
    for source, n in cases.items():
        assert len(layer_violations(path, source)) == n, source


#: Where a one-release shim may forward a name: the packages of the target layout that receive
#: code (the core, the pipelines, the metrics), never the upper readers, CLI or plots.
SHIM_HOMES = (*CORE, "pipelines", "metrics")


def _shim_table(node: ast.expr) -> dict[str, str]:
    """``{name: new module}`` of the second argument of a ``moved()`` call, read from the source:
    a dict literal (``**`` spreads included) and ``dict.fromkeys([names], "module")``."""
    if isinstance(node, ast.Dict):
        table: dict[str, str] = {}
        for key, value in zip(node.keys, node.values, strict=True):
            if key is None:
                table.update(_shim_table(value))
            else:
                table[ast.literal_eval(key)] = ast.literal_eval(value)
        return table
    if isinstance(node, ast.Call) and ast.unparse(node.func) == "dict.fromkeys":
        names, home = (ast.literal_eval(a) for a in node.args)
        return dict.fromkeys(names, home)
    raise AssertionError(f"cannot read the shim table {ast.unparse(node)!r}")


def shim_tables() -> dict[str, dict[str, str]]:
    """``{old module: {name: new module}}`` for every ``moved()`` shim in the package."""
    found: dict[str, dict[str, str]] = {}
    for path in sorted(SRC.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "moved":
                found.setdefault(_module_of(path), {}).update(_shim_table(node.args[1]))
    return found


def _module_path(module: str) -> Path | None:
    base = SRC.parent / module.replace(".", "/")
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _top_level_names(path: Path) -> set[str]:
    """Names a module defines or imports at its top level (not through ``__getattr__``)."""
    names: set[str] = set()
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.add(node.name)
        elif isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names.update(t.id for t in targets if isinstance(t, ast.Name))
        elif isinstance(node, ast.ImportFrom | ast.Import):
            names.update((a.asname or a.name).split(".")[0] for a in node.names)
    return names


def test_shims_point_at_modules_that_exist():
    """Every ``moved()`` shim forwards each name to another module of the target layout that
    exists and defines that name itself (not through a shim of its own)."""
    tables = shim_tables()
    assert {"probmap.grid.fit", "probmap.filters.localize"} <= set(tables), sorted(tables)
    for old, table in sorted(tables.items()):
        assert table, f"{old}: an empty shim"
        for name, new in sorted(table.items()):
            where = f"{old}.{name} -> {new}"
            assert new != old and new.split(".")[0] == "probmap", where
            assert new.split(".")[1] in SHIM_HOMES, where
            path = _module_path(new)
            assert path is not None, f"{where}: no such module"
            assert name in _top_level_names(path), f"{where}: the new module does not define it"


def test_shim_reader_reads_every_form():
    """The shim reader on the three forms the package uses, so that the check cannot pass by
    reading nothing."""
    calls = {
        "moved(__name__, {'fit_log': 'probmap.pipelines.fit'})": {
            "fit_log": "probmap.pipelines.fit"
        },
        "moved(__name__, dict.fromkeys(['a', 'b'], 'probmap.sim.floorplan'))": {
            "a": "probmap.sim.floorplan",
            "b": "probmap.sim.floorplan",
        },
        "moved(__name__, {**dict.fromkeys(['a'], 'probmap.x'), 'b': 'probmap.y'})": {
            "a": "probmap.x",
            "b": "probmap.y",
        },
    }
    for source, table in calls.items():
        call = ast.parse(source).body[0].value  # type: ignore[attr-defined]
        assert _shim_table(call.args[1]) == table, source


# ----------------------------------------------------------------- module cycles
def module_graph() -> dict[str, set[str]]:
    """``{module: probmap modules it imports}`` (an import of a package counts as its __init__)."""
    modules = {_module_of(p): p for p in SRC.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        targets = set()
        for m in _imported_modules(path):
            while m and m not in modules:  # probmap.grid.fit.fit_log -> probmap.grid.fit
                m = m.rpartition(".")[0]
            if m and m != name:
                targets.add(m)
        graph[name] = targets
    return graph


@pytest.mark.parametrize(
    ("a", "b"),
    [
        ("probmap.cli.mapping", "probmap.cli.distributed"),
        ("probmap.mapping.map_mapping", "probmap.mapping.sonar"),
    ],
)
def test_named_module_cycles_are_broken(a, b):
    """The two module cycles issue 19 names: each pair imports in one direction at most."""
    graph = module_graph()
    assert a in graph and b in graph
    assert not (b in graph[a] and a in graph[b]), f"{a} <-> {b}"
