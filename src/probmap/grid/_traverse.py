"""The grid traversal kernel: every cell a ray or a segment crosses, in order (private).

This is the one implementation of cell traversal in probmap. The occupancy grid's scan
integration (:mod:`probmap.grid._kernels`, :mod:`probmap.grid._semantic_kernels`), ray casting
(:func:`probmap.grid.raycast.cast_rays` and the beam model's exact and tabulated casters in
:mod:`probmap.models._beam_kernels`), the MAP mapper's beam windows
(:mod:`probmap.mapping._map_kernels`) and the RBPF's map windows
(:mod:`probmap.slam.laser._match_kernels`, through the scan kernels of :mod:`probmap.grid._kernels`)
all call the functions below, so they visit the same cells for the same ray.

The walk is the exact traversal of Amanatides and Woo (1987), in cell units (cell ``[iy, ix]``
spans ``[ix, ix + 1) x [iy, iy + 1)``): starting in the cell of the first point it steps to the
neighbouring cell whose boundary the ray crosses first, so it visits exactly the cells the ray
passes through (4-connected; at an exact corner crossing it steps in y first). Two forms:

- a **ray** from a point along a direction, stopped by the ray parameter
  (:func:`ray_start`, :func:`ray_next`; :func:`cast_exact` and :func:`ray_cells` are built on
  them): the parameter ``t`` at which the ray enters each cell is known;
- a **segment** from one point to another (:func:`walk_start`, :func:`walk_next`), which ends in
  the cell of the last point after ``|dix| + |diy|`` steps whatever the rounding (it never steps
  past the last cell on either axis), as scan integration needs.

The functions take plain scalars and contiguous arrays, trust their inputs and are inlined into
their callers (``inline="always"``), so the shared code costs nothing at run time. Note that
numba's cache does not see changes to inlined functions of another module: clear the
``__pycache__`` folders after editing this file.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_INF = np.inf


@njit(cache=True, inline="always")
def axis_setup(g0, d):  # pragma: no cover - compiled
    """Per-axis set-up of the walk for a ray from ``g0`` (cell units) with extent ``d`` along the
    axis: ``(step, t_delta, t_max)``, the step direction, the ray parameter between two
    boundaries and the parameter of the first boundary crossed."""
    i = math.floor(g0)
    if d > 0.0:
        td = 1.0 / d
        return 1, td, (i + 1.0 - g0) * td
    if d < 0.0:
        td = -1.0 / d
        return -1, td, (g0 - i) * td
    return 0, _INF, _INF


@njit(cache=True, inline="always")
def ray_start(gx, gy, dx, dy):  # pragma: no cover - compiled
    """State of the walk along a ray from grid point ``(gx, gy)`` with direction ``(dx, dy)``.

    Returns ``(ix, iy, sx, sy, tmx, tmy, tdx, tdy)``: the first cell, the step directions, the
    ray parameters of the next x / y boundary and between two boundaries. The ray enters the
    first cell at parameter 0; :func:`ray_next` gives the next cell and its entry parameter.
    With a unit direction the parameter is the distance travelled in cells.
    """
    ix = int(math.floor(gx))
    iy = int(math.floor(gy))
    sx, tdx, tmx = axis_setup(gx, dx)
    sy, tdy, tmy = axis_setup(gy, dy)
    return ix, iy, sx, sy, tmx, tmy, tdx, tdy


@njit(cache=True, inline="always")
def ray_next(ix, iy, sx, sy, tmx, tmy, tdx, tdy):  # pragma: no cover - compiled
    """One step of the ray walk started by :func:`ray_start`: returns ``(ix, iy, t, tmx, tmy)``,
    the next cell and the parameter ``t`` at which the ray enters it."""
    if tmx < tmy:
        t = tmx
        ix += sx
        tmx += tdx
    else:
        t = tmy
        iy += sy
        tmy += tdy
    return ix, iy, t, tmx, tmy


@njit(cache=True, inline="always")
def cast_exact(occ, gx, gy, dx, dy, limit):  # pragma: no cover - compiled
    """Ray parameter where the ray first enters an occupied cell of boolean map ``occ``.

    From grid point ``(gx, gy)`` along the unit direction ``(dx, dy)`` (cell units), visit every
    cell the ray crosses in order; return the parameter (cells) at which it enters the first
    occupied cell (0 when it starts in one), or ``limit`` when it leaves the ``(H, W)`` map or
    passes ``limit`` first (a cell entered at exactly ``limit`` is not looked at).
    """
    h, w = occ.shape
    ix, iy, sx, sy, tmx, tmy, tdx, tdy = ray_start(gx, gy, dx, dy)
    t = 0.0
    while t < limit:
        if ix < 0 or iy < 0 or ix >= w or iy >= h:
            return limit
        if occ[iy, ix]:
            return t
        ix, iy, t, tmx, tmy = ray_next(ix, iy, sx, sy, tmx, tmy, tdx, tdy)
    return limit


@njit(cache=True, inline="always")
def ray_cells(gx, gy, dx, dy, length, w, h, cells, dists, n):  # pragma: no cover - compiled
    """Append to ``cells`` / ``dists`` (from slot ``n``) the cells a ray enters before ``length``.

    From grid point ``(gx, gy)`` along the unit direction ``(dx, dy)`` (cell units); ``cells``
    receives the flat index ``iy * w + ix`` and ``dists`` the parameter (cells) at which the ray
    enters the cell (0 for the start cell). Cells outside the ``h x w`` grid are skipped (the
    walk goes on through them). Returns the new count.
    """
    ix, iy, sx, sy, tmx, tmy, tdx, tdy = ray_start(gx, gy, dx, dy)
    t = 0.0
    while t < length:
        if 0 <= ix < w and 0 <= iy < h:
            cells[n] = iy * w + ix
            dists[n] = t
            n += 1
        ix, iy, t, tmx, tmy = ray_next(ix, iy, sx, sy, tmx, tmy, tdx, tdy)
    return n


@njit(cache=True, inline="always")
def walk_start(gx0, gy0, gx1, gy1, include_last):  # pragma: no cover - compiled
    """State of the walk along the segment from grid point (gx0, gy0) to (gx1, gy1).

    Returns ``(ix, iy, ex, ey, sx, sy, tmx, tmy, tdx, tdy, n)``: the first cell, the last cell,
    the step directions, the segment parameters (0 at the first point, 1 at the last) of the next
    x / y boundary and between boundaries, and the number of cells to visit (the last one only
    if ``include_last``). Visit ``n`` cells, calling :func:`walk_next` after each.
    """
    ix, iy, sx, sy, tmx, tmy, tdx, tdy = ray_start(gx0, gy0, gx1 - gx0, gy1 - gy0)
    ex = int(math.floor(gx1))
    ey = int(math.floor(gy1))
    n = abs(ex - ix) + abs(ey - iy)
    if include_last:
        n += 1
    return ix, iy, ex, ey, sx, sy, tmx, tmy, tdx, tdy, n


@njit(cache=True, inline="always")
def walk_next(ix, iy, ex, ey, sx, sy, tmx, tmy, tdx, tdy):  # pragma: no cover - compiled
    """One step of the segment walk started by :func:`walk_start`: returns ``(ix, iy, tmx, tmy)``.

    Once the walk has reached the last cell's column (row), it steps only in y (x): rounding in
    the boundary parameters can then never carry it past the last cell.
    """
    if ix == ex:
        iy += sy
        tmy += tdy
    elif iy == ey:
        ix += sx
        tmx += tdx
    elif tmx < tmy:
        ix += sx
        tmx += tdx
    else:
        iy += sy
        tmy += tdy
    return ix, iy, tmx, tmy
