"""Deprecated path of the localization pipeline, now :mod:`probmap.pipelines.localize`.

A map and a laser log to an MCL trajectory is a pipeline, not filter core. This path works for
one release: importing it imports nothing of the pipeline, and each old name is forwarded, with
a ``DeprecationWarning``, when it is looked up.
"""

from __future__ import annotations

from probmap._deprecation import moved

__getattr__ = moved(
    __name__,
    dict.fromkeys(
        [
            "LocalizationRun",
            "LocalizeConfig",
            "localize_scans",
            "match_times",
            "trajectory_errors",
        ],
        "probmap.pipelines.localize",
    ),
)
