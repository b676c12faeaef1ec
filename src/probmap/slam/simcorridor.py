"""Deprecated path of the simulated corridor loop, now :mod:`probmap.sim.corridor`.

This path works for one release: importing it imports nothing of the new home, and each old
name is forwarded, with a ``DeprecationWarning``, when it is looked up.
"""

from __future__ import annotations

from probmap._deprecation import moved

__getattr__ = moved(
    __name__,
    dict.fromkeys(["corridor_plan", "simulate_corridor_loop"], "probmap.sim.corridor"),
)
