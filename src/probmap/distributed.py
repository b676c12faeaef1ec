"""Deprecated path of distributed mapping.

The increments and their sums (core) are now :mod:`probmap.grid.increments`; the Dask pipeline
is :mod:`probmap.pipelines.distributed`. This path works for one release: importing it imports
neither, and each old name is forwarded, with a ``DeprecationWarning``, when it is looked up.
"""

from __future__ import annotations

from probmap._deprecation import moved

__getattr__ = moved(
    __name__,
    {
        **dict.fromkeys(
            [
                "IncrementGrid",
                "SemanticIncrements",
                "clamping_bound",
                "integrate_increments",
                "integrate_semantic_increments",
                "tree_sum",
            ],
            "probmap.grid.increments",
        ),
        **dict.fromkeys(
            [
                "DistributedMappingError",
                "DistributedMappingResult",
                "DistributedOptions",
                "SemanticMappingResult",
                "local_cluster",
                "map_labelled_distributed",
                "map_logs_distributed",
            ],
            "probmap.pipelines.distributed",
        ),
    },
)
