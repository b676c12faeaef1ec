"""The one-release deprecation shims left where moved code used to live (issue 19).

Each old path forwards every name that moved to the very same object in its new home (a
pipeline, ``probmap.sim``, ``probmap.mapping``, ``probmap.models`` or ``probmap.metrics``), with a
``DeprecationWarning`` naming the new path; importing an old module imports no pipeline;
unknown names still raise ``AttributeError``.
"""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

#: old module -> {new module: names that moved there}
SHIMS = {
    "probmap.grid.fit": {
        "probmap.pipelines.fit": ["fit_log"],
        "probmap.models.beam": ["FitResult", "component_densities", "fit_beam_model"],
    },
    "probmap.grid.forward": {
        "probmap.models.beam": ["BeamModel"],
        "probmap.models.likelihood_field": ["LikelihoodField"],
        "probmap.models.grid_map": ["GridGeometry", "occupied_mask"],
    },
    "probmap.slam.gridslam": {"probmap.pipelines.grid_slam": ["slam_log", "write_trajectory"]},
    "probmap.slam.pipeline": {
        "probmap.pipelines.landmark_slam": [
            "GPS_MAX_SPEED",
            "SlamResult",
            "dead_reckoning",
            "default_ekf_config",
            "evaluate",
            "run_landmark_slam",
            "write_slam_outputs",
        ],
    },
    "probmap.filters.localize": {
        "probmap.pipelines.localize": [
            "LocalizationRun",
            "LocalizeConfig",
            "localize_scans",
            "match_times",
            "trajectory_errors",
        ],
    },
    "probmap.filters.demo": {
        "probmap.pipelines.demo": ["run_localize_demo"],
        "probmap.sim.localization": ["LocalizationWorld", "simulate_localization_world"],
    },
    "probmap.pipelines.demo": {
        "probmap.sim.localization": ["LocalizationWorld", "simulate_localization_world"],
    },
    "probmap.grid.semantic_sim": {
        "probmap.pipelines.semantic": ["run_semantic_demo"],
        "probmap.sim.semantic": [
            "SEMANTIC_CLASSES",
            "SimulatedLabelledWorld",
            "labelled_floor_plan",
            "map_labelled_world",
            "simulate_labelled_world",
        ],
        "probmap.metrics.map": ["Reliability", "reliability", "semantic_iou", "truth_on_grid"],
    },
    "probmap.grid.simworld": {
        "probmap.sim.laser": ["SimulatedLaserWorld"],
        "probmap.sim.floorplan": ["floor_plan", "simulate_laser_world"],
        "probmap.metrics.map": ["map_accuracy"],
    },
    "probmap.slam.simcorridor": {
        "probmap.sim.corridor": ["corridor_plan", "simulate_corridor_loop"],
    },
    "probmap.grid.map_mapping": {
        "probmap.mapping.map_mapping": [
            "BeamIndex",
            "MapMapper",
            "MapMappingConfig",
            "MapMappingResult",
            "SweepRecord",
            "cone_log_odds_grid",
            "cone_offsets",
            "map_mapping",
        ],
        "probmap.models.beam": ["BeamModelParams"],
    },
    "probmap.grid.sonar": {
        "probmap.mapping.sonar": [
            "SonarWorld",
            "cone_log_odds_grid",
            "corridor_with_door",
            "simulate_cone_ranges",
        ],
    },
    "probmap.grid._map_kernels": {
        "probmap.mapping._map_kernels": [
            "all_gains",
            "apply_flip",
            "build_entries",
            "evaluate_beams",
            "flip_gain",
            "invert_entries",
            "sweep",
        ],
        "probmap.models._beam_kernels": ["beam_log_likelihood", "beam_log_likelihoods"],
    },
    "probmap.grid._forward_kernels": {
        "probmap.models._beam_kernels": [
            "beam_log_likelihood",
            "beam_mixture",
            "cast_fan",
            "cast_rays",
            "exact_ranges",
            "fill_entry",
            "heading_bin",
            "table_beam_model",
            "table_normalisers",
            "table_ranges",
        ],
        "probmap.models._likelihood_field_kernels": [
            "endpoints_in_robot_frame",
            "likelihood_field_per_beam",
            "likelihood_field_sum",
        ],
        "probmap.grid._traverse": ["axis_setup", "cast_exact"],
    },
}

CASES = [
    (old, new, name)
    for old, homes in SHIMS.items()
    for new, names in homes.items()
    for name in names
]


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
    for homes in SHIMS.values():
        for new, names in homes.items():
            if new.rpartition(".")[2].startswith("_"):
                continue  # a private kernel module has no __all__
            exported = importlib.import_module(new).__all__
            assert {n for n in names if not n.isupper()} <= set(exported), new  # constants aside


def test_importing_the_old_modules_imports_no_pipeline():
    """The shims are lazy: a fresh interpreter that imports every old module of the core has
    loaded none of ``probmap.pipelines``, ``datasets``, ``cli`` or ``viz``."""
    core = [old for old in SHIMS if not old.startswith("probmap.pipelines.")]
    code = (
        "import sys\n"
        + "".join(f"import {old}\n" for old in core)
        + "bad = sorted(m for m in sys.modules if m.split('.')[:2] in "
        + "(['probmap', 'pipelines'], ['probmap', 'datasets'], ['probmap', 'cli'], "
        + "['probmap', 'viz']))\n"
        + "print(bad)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
