"""Numba twins of :mod:`probmap.geometry.se2`'s scalar primitives, for compiled loops (private).

Kernels of other packages (the landmark SLAM kernels, the pose-graph kernels) call these inside
their loops. Inputs are plain floats, trusted.
"""

from __future__ import annotations

import math

from numba import njit

__all__ = ["wrap"]

_TWO_PI = 2.0 * math.pi


@njit(cache=True)
def wrap(a):  # pragma: no cover - compiled
    """Angle ``a`` (rad) wrapped to ``[-pi, pi)``, as :func:`probmap.geometry.se2.wrap_angle`."""
    return a - _TWO_PI * math.floor((a + math.pi) / _TWO_PI)
