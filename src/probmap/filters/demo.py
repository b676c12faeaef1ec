"""Deprecated path of the localization demo, now :mod:`probmap.pipelines.demo`.

A simulated world, an MCL run and its CSV files are a pipeline, not filter core. This path works
for one release: importing it imports nothing of the pipeline, and each old name is forwarded,
with a ``DeprecationWarning``, when it is looked up.
"""

from __future__ import annotations

from probmap._deprecation import moved

__getattr__ = moved(
    __name__,
    dict.fromkeys(
        [
            "LocalizationWorld",
            "run_localize_demo",
            "simulate_localization_world",
        ],
        "probmap.pipelines.demo",
    ),
)
