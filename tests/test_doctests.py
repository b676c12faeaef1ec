"""Run the docstring examples of every probmap module (they are documentation that must stay true).

The one doctest runner of the test suite: it finds every module of the package whose source holds
an example (``>>>``) and runs them with the project's option flags.  ``pytest --doctest-modules``
is not used because it would also collect the CLI and optional-dependency modules at import time.
"""

from __future__ import annotations

import doctest
import importlib
from pathlib import Path

import pytest

import probmap

SRC = Path(probmap.__file__).resolve().parent
FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE

#: Modules whose examples must not quietly disappear, with the least number of examples each.
MIN_EXAMPLES = {
    "probmap.datasets.ros.tf": 2,
    "probmap.filters.kld": 1,
    "probmap.filters.resampling": 1,
    "probmap.grid.logodds": 1,
    "probmap.grid.occupancy": 1,
    "probmap.grid.raycast": 1,
    "probmap.grid.semantic": 1,
    "probmap.grid.semantic_io": 1,
    "probmap.grid.spec": 1,
    "probmap.mapping.map_mapping": 1,
    "probmap.models.beam": 2,
    "probmap.slam.posegraph.optimize": 1,
}


def _module_name(path: Path) -> str:
    parts = path.relative_to(SRC.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules_with_examples() -> list[str]:
    """Every module of the package whose source has a ``>>>`` prompt."""
    found = [
        _module_name(p)
        for p in sorted(SRC.rglob("*.py"))
        if ">>> " in p.read_text(encoding="utf-8")
    ]
    return sorted(found)


MODULES = modules_with_examples()


def test_discovery_finds_the_known_modules():
    missing = sorted(set(MIN_EXAMPLES) - set(MODULES))
    assert not missing, f"no examples found in {missing}"


@pytest.mark.parametrize("name", MODULES)
def test_doctests(name):
    module = importlib.import_module(name)
    tests = doctest.DocTestFinder().find(module, name)
    # examples marked ``# doctest: +SKIP`` (e.g. ones that need a real log) are not run
    runnable = sum(not ex.options.get(doctest.SKIP) for t in tests for ex in t.examples)
    result = doctest.testmod(module, optionflags=FLAGS)
    assert result.attempted == runnable
    assert result.attempted >= MIN_EXAMPLES.get(name, 0), f"{name} has no examples"
    assert result.failed == 0
