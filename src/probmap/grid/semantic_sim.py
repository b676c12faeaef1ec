"""Deprecated path of the simulated labelled world, now :mod:`probmap.sim.semantic`.

The simulator moved to :mod:`probmap.sim.semantic`, the scores (IoU, reliability, the truth on
a map's grid) to :mod:`probmap.metrics.map` and the demo to :mod:`probmap.pipelines.semantic`.
This path works for one release: importing it imports nothing of the new homes, and each old
name is forwarded, with a ``DeprecationWarning``, when it is looked up.
"""

from __future__ import annotations

from probmap._deprecation import moved

__getattr__ = moved(
    __name__,
    {
        **dict.fromkeys(
            [
                "SEMANTIC_CLASSES",
                "SimulatedLabelledWorld",
                "labelled_floor_plan",
                "map_labelled_world",
                "simulate_labelled_world",
            ],
            "probmap.sim.semantic",
        ),
        **dict.fromkeys(
            ["Reliability", "reliability", "semantic_iou", "truth_on_grid"], "probmap.metrics.map"
        ),
        "run_semantic_demo": "probmap.pipelines.semantic",
    },
)
