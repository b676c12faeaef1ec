"""Run the docstring examples of the public modules (they are documentation that must stay true)."""

from __future__ import annotations

import doctest
import importlib

import pytest

MODULES = [
    "probmap.grid.spec",
    "probmap.grid.logodds",
    "probmap.grid.occupancy",
    "probmap.grid.raycast",
    "probmap.slam.posegraph",
]


@pytest.mark.parametrize("name", MODULES)
def test_doctests(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0, f"{name} has no examples"
    assert result.failed == 0
