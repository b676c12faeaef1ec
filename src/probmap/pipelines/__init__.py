"""Pipelines: a dataset, an algorithm and its outputs, run end to end with results.

The core algorithms never import this package; the CLI calls it and only prints what it returns.
Mapping with known poses lives in :mod:`probmap.pipelines.mapping` and the output rule that every
command shares in :mod:`probmap.pipelines.outputs`; both are re-exported here, where the README
imports them from. The other pipelines are the modules of this package (``localize``,
``grid_slam``, ``landmark_slam``, ``pose_graph``, ``fit``, ``semantic``, ``distributed``,
``demo``).
"""

from __future__ import annotations

from probmap.pipelines.mapping import (
    DemoResult,
    MappingConfig,
    MappingResult,
    map_log,
    map_log_map,
    run_mapping_demo,
    write_map,
)
from probmap.pipelines.outputs import check_output_folder, check_output_prefix

__all__ = [
    "DemoResult",
    "MappingConfig",
    "MappingResult",
    "check_output_folder",
    "check_output_prefix",
    "map_log",
    "map_log_map",
    "run_mapping_demo",
    "write_map",
]
