"""Deprecated path of MAP occupancy grid mapping, now :mod:`probmap.mapping.map_mapping`.

MAP mapping (Table 9.3) is an algorithm above the grid, not grid storage, so it has its own
package; the beam model's parameters it uses, :class:`~probmap.models.beam.BeamModelParams`,
live with the sensor models. This path works for one release: importing it imports nothing of
the new homes, and each old name is forwarded, with a ``DeprecationWarning``, when it is looked
up.
"""

from __future__ import annotations

from probmap._deprecation import moved

__getattr__ = moved(
    __name__,
    {
        # the old path's names, spelled out: a shim imports nothing of the new home (its __all__)
        **dict.fromkeys(
            [
                "BeamIndex",
                "MapMapper",
                "MapMappingConfig",
                "MapMappingResult",
                "SweepRecord",
                "cone_log_odds_grid",
                "cone_offsets",
                "map_mapping",
            ],
            "probmap.mapping.map_mapping",
        ),
        "BeamModelParams": "probmap.models.beam",
    },
)
