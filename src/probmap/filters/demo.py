"""Deprecated path of the localization demo, now :mod:`probmap.pipelines.demo`.

A simulated world, an MCL run and its CSV files are a pipeline, not filter core; the world
itself is a simulator (:mod:`probmap.sim.localization`). This path works for one release:
importing it imports nothing of the new homes, and each old name is forwarded, with a
``DeprecationWarning``, when it is looked up.
"""

from __future__ import annotations

from probmap._deprecation import moved

__getattr__ = moved(
    __name__,
    {
        "LocalizationWorld": "probmap.sim.localization",
        "run_localize_demo": "probmap.pipelines.demo",
        "simulate_localization_world": "probmap.sim.localization",
    },
)
