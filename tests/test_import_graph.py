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


def layer_violations(path: Path, source: str | None = None) -> list[str]:
    """Why the core file ``path`` breaks the layer rule (empty when it keeps it).

    Two kinds: an ``import`` (anywhere in the file, at the top or inside a function) of an upper
    package, and a string naming an upper module (``importlib.import_module("probmap.cli...")``,
    ``__import__``).
    """
    text = path.read_text(encoding="utf-8") if source is None else source
    tree = ast.parse(text)
    bad = [
        f"imports {m}" for m in sorted(_imported_modules(path, text)) if m.split(".")[1] in UPPER
    ]
    prefixes = tuple(f"probmap.{u}" for u in UPPER)
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Constant)
            and isinstance(node.value, str)
            and node.value.startswith(prefixes)
            and node.value.split(".")[1] in UPPER  # probmap.cli, not probmap.climb
            and " " not in node.value  # a module name, not prose in a docstring
        ):
            bad.append(f"names {node.value!r} (line {node.lineno})")
    return bad


def test_core_imports_no_datasets_pipelines_cli_or_viz():
    files = _core_files()
    assert len(files) > 40 and {"grid", "slam", "filters"} <= {p.parts[-2] for p in files}
    bad = {str(p.relative_to(SRC)): v for p in files if (v := layer_violations(p))}
    assert not bad, "the core reaches up a layer: " + "; ".join(f"{k}: {v}" for k, v in bad.items())


def test_layer_rule_catches_every_form(tmp_path):
    """The checker itself: it sees function-level, relative and ``from probmap import`` imports
    and import_module strings."""
    path = SRC / "grid" / "example.py"  # never written: only names the module for resolution
    cases = {
        "from probmap.datasets.carmen import load_scans": 1,
        "def f():\n    import probmap.viz.landmark_slam\n": 1,
        "from ..pipelines import grid_slam": 1,
        "from .. import cli": 1,
        "from probmap import datasets": 1,
        "import importlib\nimportlib.import_module('probmap.pipelines.fit')": 1,
        "from probmap.grid.spec import GridSpec\nfrom probmap import errors": 0,
        '"""See probmap.pipelines.fit for the log reader."""': 0,
    }
    for source, n in cases.items():
        assert len(layer_violations(path, source)) == n, source


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


# ----------------------------------------------------------------- the SLAM wing's walls
def _wing(module: str) -> str | None:
    """``laser`` or ``landmark`` for a module of ``probmap.slam.laser``/``probmap.slam.landmark``."""
    parts = module.split(".")
    return parts[2] if len(parts) > 2 and parts[:2] == ["probmap", "slam"] else None


def wing_violations(graph: dict[str, set[str]]) -> list[str]:
    """Imports from laser SLAM into landmark SLAM or back."""
    walls = {("laser", "landmark"), ("landmark", "laser")}
    return [
        f"{a} imports {b}"
        for a, targets in sorted(graph.items())
        for b in sorted(targets)
        if (_wing(a), _wing(b)) in walls
    ]


def test_laser_and_landmark_slam_never_import_each_other():
    graph = module_graph()
    assert "probmap.slam.laser.submap_slam" in graph and "probmap.slam.landmark.ekf" in graph
    assert not wing_violations(graph), wing_violations(graph)


def test_wing_rule_catches_a_planted_import():
    graph = {
        "probmap.slam.laser.rbpf": {"probmap.slam.landmark.association", "probmap.grid.spec"},
        "probmap.slam.landmark.ekf": {"probmap.slam.posegraph.optimize"},
    }
    assert wing_violations(graph) == [
        "probmap.slam.laser.rbpf imports probmap.slam.landmark.association"
    ]


# ----------------------------------------------------------------- no files in the algorithms
#: The algorithm packages: arrays in, arrays out; reading and writing files is the job of
#: ``datasets``, ``grid.io`` and the pipelines.
ALGORITHMS = ("slam", "filters", "models", "geometry", "mapping")
#: Modules whose import means serialization or file access.
_FILE_MODULES = {"pickle", "shelve", "marshal", "dill", "cloudpickle", "tempfile", "shutil"}
_FILE_MODULES |= {"gzip", "bz2", "lzma", "zipfile", "tarfile", "probmap._atomic"}
#: Calls that open, read or write files (a name or the last part of an attribute).
_FILE_CALLS = {"open", "read_text", "write_text", "read_bytes", "write_bytes", "tofile"}
_FILE_CALLS |= {"load", "save", "savez", "savez_compressed", "loadtxt", "savetxt", "fromfile"}
_FILE_CALLS |= {"genfromtxt", "remove", "unlink", "rename", "replace", "mkdir", "makedirs"}


def file_violations(source: str) -> list[str]:
    """Why a module of an algorithm package touches files (empty when it does not).

    ``replace`` is read as a file operation only as ``os.replace`` or on a path, not as
    ``dataclasses.replace`` or ``str.replace``: a call with one argument or a keyword argument
    is not ``os.replace(src, dst)``.
    """
    bad: list[str] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import | ast.ImportFrom):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.module:
                names.append(node.module)
            bad += [f"imports {n} (line {node.lineno})" for n in names if n in _FILE_MODULES]
        elif isinstance(node, ast.Call):
            func = node.func
            name = func.id if isinstance(func, ast.Name) else getattr(func, "attr", None)
            if name not in _FILE_CALLS:
                continue
            if name == "replace" and (
                not isinstance(func, ast.Attribute)
                or ast.unparse(func.value) not in ("os", "Path", "path")
            ):
                continue
            if name in ("load", "save") and not (
                isinstance(func, ast.Attribute) and ast.unparse(func.value) in ("np", "numpy")
            ):
                continue
            if name == "open" and isinstance(func, ast.Attribute):
                if ast.unparse(func.value) not in ("os", "io", "Path", "path", "gzip", "bz2"):
                    continue
            bad.append(f"calls {ast.unparse(func)} (line {node.lineno})")
    return bad


def test_algorithm_packages_open_no_files_and_use_no_pickle():
    files = [p for pkg in ALGORITHMS for p in sorted((SRC / pkg).rglob("*.py"))]
    assert len(files) > 30
    bad = {
        str(p.relative_to(SRC)): v
        for p in files
        if (v := file_violations(p.read_text(encoding="utf-8")))
    }
    assert not bad, "file access in an algorithm package: " + "; ".join(
        f"{k}: {v}" for k, v in bad.items()
    )


def test_file_rule_catches_every_form():
    cases = {
        "import pickle": 1,
        "from pickle import dumps": 1,
        "from probmap._atomic import atomic_write": 1,
        "with open(p) as f: pass": 1,
        "Path(p).write_text('x')": 1,
        "np.savez(p, a=a)": 1,
        "x = np.load(p)": 1,
        "os.replace(a, b)": 1,
        "import shutil": 1,
        "cfg = dataclasses.replace(cfg, a=1)": 0,
        "s = 'a'.replace('a', 'b')": 0,
        "x = self.load(3)": 0,
        "import numpy as np\nx = np.zeros(3)": 0,
    }
    for source, n in cases.items():
        assert len(file_violations(source)) == n, source


# ----------------------------------------------------------------- names and sizes
def _names() -> set[str]:
    """Every module and package name of probmap (``_kernels``, ``submap_slam``, ``laser``)."""
    names = {p.stem for p in SRC.rglob("*.py") if p.stem != "__init__"}
    return names | {p.parent.name for p in SRC.rglob("__init__.py")}


def underscore_twins(names: set[str]) -> list[set[str]]:
    """Groups of names that differ only by underscores or case."""
    groups: dict[str, set[str]] = {}
    for n in names:
        groups.setdefault(n.replace("_", "").lower(), set()).add(n)
    return [g for g in groups.values() if len(g) > 1]


def test_no_two_module_names_differ_only_by_underscores():
    names = _names()
    assert {"submap_slam", "rbpf", "laser", "landmark", "posegraph"} <= names
    assert not underscore_twins(names), underscore_twins(names)
    assert underscore_twins({"graph_slam", "graphslam", "ekf"}) == [{"graph_slam", "graphslam"}]


def test_no_module_over_1000_lines_but_the_kernels():
    long = {
        str(p.relative_to(SRC)): n
        for p in SRC.rglob("*.py")
        if "_kernels" not in p.stem
        and (n := len(p.read_text(encoding="utf-8").splitlines())) > 1000
    }
    assert not long, long


# ----------------------------------------------------------------- no pickle anywhere
#: What loads or writes a pickle (issue 38: a session or any other file must never run code).
_PICKLE_MODULES = {"pickle", "_pickle", "cPickle", "shelve", "dill", "cloudpickle", "joblib"}


def pickle_uses(source: str) -> list[str]:
    """Where a module imports a pickle module or asks numpy for pickles (empty when never)."""
    bad: list[str] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import | ast.ImportFrom):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.module:
                names.append(node.module)
            bad += [f"imports {n} (line {node.lineno})" for n in names if n in _PICKLE_MODULES]
        elif isinstance(node, ast.keyword) and node.arg == "allow_pickle":
            if not (isinstance(node.value, ast.Constant) and node.value.value is False):
                bad.append(f"allow_pickle={ast.unparse(node.value)} (line {node.value.lineno})")
    return bad


def test_no_pickle_anywhere_in_the_package():
    files = sorted(SRC.rglob("*.py"))
    bad = {
        str(p.relative_to(SRC)): v
        for p in files
        if (v := pickle_uses(p.read_text(encoding="utf-8")))
    }
    assert not bad, "pickle in probmap: " + "; ".join(f"{k}: {v}" for k, v in bad.items())


def test_pickle_rule_catches_every_form():
    cases = {
        "import pickle": 1,
        "from pickle import loads": 1,
        "import cloudpickle as cp": 1,
        "np.load(p, allow_pickle=True)": 1,
        "np.load(p, allow_pickle=flag)": 1,
        "np.load(p, allow_pickle=False)": 0,
        "json.loads(text)": 0,
    }
    for source, n in cases.items():
        assert len(pickle_uses(source)) == n, source
