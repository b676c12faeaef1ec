"""Deprecated path of the simulated floor plan, now :mod:`probmap.sim.floorplan`.

The simulators have one package, :mod:`probmap.sim` (the laser world's record is
:class:`probmap.sim.laser.SimulatedLaserWorld`), and the map score moved to the map metrics
(:func:`probmap.metrics.map.map_accuracy`). This path works for one release: importing it
imports nothing of the new homes, and each old name is forwarded, with a ``DeprecationWarning``,
when it is looked up.
"""

from __future__ import annotations

from probmap._deprecation import moved

__getattr__ = moved(
    __name__,
    {
        "SimulatedLaserWorld": "probmap.sim.laser",
        "floor_plan": "probmap.sim.floorplan",
        "simulate_laser_world": "probmap.sim.floorplan",
        "map_accuracy": "probmap.metrics.map",
    },
)
