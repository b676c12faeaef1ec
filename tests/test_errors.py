"""probmap.errors is the one home of the exception classes; the old import paths still work."""

from __future__ import annotations

import warnings

import pytest

from probmap import errors
from probmap.datasets import carmen, protocol
from probmap.datasets.ros import scans as ros_scans
from probmap.filters import particle
from probmap.grid import io as grid_io
from probmap.grid import occupancy, semantic_io
from probmap.slam.landmark import seif


@pytest.mark.parametrize(
    ("module", "name"),
    [
        (protocol, "DatasetError"),
        (ros_scans, "BagError"),
        (grid_io, "MapFileError"),
        (semantic_io, "SemanticFileError"),
        (carmen, "BadLinesWarning"),
        (seif, "SingularInformationError"),
        (particle, "ParticleFilterWarning"),
        (occupancy, "GridBoundsError"),
    ],
)
def test_old_import_path_is_the_same_class(module, name):
    assert getattr(module, name) is getattr(errors, name)


def test_hierarchy():
    for cls in (errors.BagError, errors.MapFileError, errors.SemanticFileError):
        assert issubclass(cls, errors.DatasetError)
    assert issubclass(errors.DatasetError, ValueError)
    assert issubclass(errors.SingularInformationError, ValueError)
    assert issubclass(errors.GridBoundsError, ValueError)
    assert issubclass(errors.BadLinesWarning, UserWarning)
    assert issubclass(errors.ParticleFilterWarning, UserWarning)


def test_dataset_error_names_the_place():
    exc = errors.DatasetError("bad value", path="log.txt", line=3, field="x")
    assert str(exc) == "log.txt, line 3, field 'x': bad value"
    assert (exc.path, exc.line, exc.field) == ("log.txt", 3, "x")
    assert str(errors.DatasetError("plain")) == "plain"


def test_warnings_are_catchable():
    with pytest.warns(errors.BadLinesWarning):
        warnings.warn("skipped", errors.BadLinesWarning, stacklevel=1)


def test_errors_imports_nothing_from_the_package():
    import ast
    from pathlib import Path

    tree = ast.parse(Path(errors.__file__).read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            assert not (node.module or "").startswith("probmap")
        elif isinstance(node, ast.Import):
            assert not any(a.name.startswith("probmap") for a in node.names)
