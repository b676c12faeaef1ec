"""Deprecated path of the wide-beam (sonar cone) sensors, now :mod:`probmap.mapping.sonar`.

This path works for one release: importing it imports nothing of the new home, and each old
name is forwarded, with a ``DeprecationWarning``, when it is looked up.
"""

from __future__ import annotations

from probmap._deprecation import moved

__getattr__ = moved(
    __name__,
    dict.fromkeys(
        ["SonarWorld", "cone_log_odds_grid", "corridor_with_door", "simulate_cone_ranges"],
        "probmap.mapping.sonar",
    ),
)
