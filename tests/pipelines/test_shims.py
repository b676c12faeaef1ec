"""The one-release deprecation shims left where the pipelines used to live (issue 19).

Each old path forwards every name that moved to the very same object in ``probmap.pipelines``,
with a ``DeprecationWarning`` naming the new path; importing an old module imports no pipeline;
unknown names still raise ``AttributeError``.
"""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

#: old module -> (new module, names that moved)
SHIMS = {
    "probmap.grid.fit": ("probmap.pipelines.fit", ["fit_log"]),
    "probmap.slam.gridslam": ("probmap.pipelines.grid_slam", ["slam_log", "write_trajectory"]),
    "probmap.slam.pipeline": (
        "probmap.pipelines.landmark_slam",
        [
            "GPS_MAX_SPEED",
            "SlamResult",
            "dead_reckoning",
            "default_ekf_config",
            "evaluate",
            "run_landmark_slam",
            "write_slam_outputs",
        ],
    ),
    "probmap.filters.localize": (
        "probmap.pipelines.localize",
        ["LocalizationRun", "LocalizeConfig", "localize_scans", "match_times", "trajectory_errors"],
    ),
    "probmap.filters.demo": (
        "probmap.pipelines.demo",
        ["LocalizationWorld", "run_localize_demo", "simulate_localization_world"],
    ),
    "probmap.grid.semantic_sim": ("probmap.pipelines.semantic", ["run_semantic_demo"]),
}

CASES = [(old, new, name) for old, (new, names) in SHIMS.items() for name in names]


@pytest.mark.parametrize(("old", "new", "name"), CASES)
def test_old_path_warns_and_forwards(old, new, name):
    old_mod = importlib.import_module(old)
    with pytest.warns(DeprecationWarning, match=rf"{old}\.{name} has moved to {new}\.{name}"):
        obj = getattr(old_mod, name)
    assert obj is getattr(importlib.import_module(new), name)


@pytest.mark.parametrize(("old", "new", "name"), CASES[:1] + CASES[-1:])
def test_from_import_of_an_old_name_still_works(old, new, name):
    with pytest.warns(DeprecationWarning):
        namespace: dict[str, object] = {}
        exec(f"from {old} import {name}", namespace)
    assert namespace[name] is getattr(importlib.import_module(new), name)


@pytest.mark.parametrize("old", sorted(SHIMS))
def test_unknown_names_still_raise(old):
    with pytest.raises(AttributeError, match="no_such_name"):
        _ = importlib.import_module(old).no_such_name


def test_new_modules_export_what_moved():
    for new, names in SHIMS.values():
        exported = importlib.import_module(new).__all__
        assert {n for n in names if not n.isupper()} <= set(exported), new  # constants aside


def test_importing_the_old_modules_imports_no_pipeline():
    """The shims are lazy: a fresh interpreter that imports every old module has loaded none of
    ``probmap.pipelines``, ``datasets``, ``cli`` or ``viz``."""
    code = (
        "import sys\n"
        + "".join(f"import {old}\n" for old in SHIMS)
        + "bad = sorted(m for m in sys.modules if m.split('.')[:2] in "
        + "(['probmap', 'pipelines'], ['probmap', 'datasets'], ['probmap', 'cli'], "
        + "['probmap', 'viz']))\n"
        + "print(bad)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
