"""The one grid traversal kernel (``probmap.grid._traverse``) against the walks it replaced.

Before issue 19 the exact walk was written out in four kernels: the ray caster of
``grid/_kernels.py``, ``cast_exact`` of the forward models, ``_walk`` of the MAP mapper and the
segment walk of scan integration. Each test below runs a plain-Python copy of one of the old
loops on random rays and asserts that the shared kernel gives exactly the same numbers.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from probmap.grid import _traverse as T
from probmap.grid.raycast import cast_rays
from probmap.grid.spec import GridSpec
from probmap.models.beam import BeamModel


def _axis_setup(g0, d):
    i = math.floor(g0)
    if d > 0.0:
        return 1, 1.0 / d, (i + 1.0 - g0) * (1.0 / d)
    if d < 0.0:
        return -1, -1.0 / d, (g0 - i) * (-1.0 / d)
    return 0, math.inf, math.inf


def old_cast_rays(occ, ox, oy, res, poses, angles, max_range):
    """The loop of ``grid._kernels.cast_rays`` before the merge (note ``t <= limit``)."""
    h, w = occ.shape
    out = np.empty((len(poses), len(angles)))
    for p, (x, y, th) in enumerate(poses):
        px, py = (x - ox) / res, (y - oy) / res
        for b, a in enumerate(angles):
            dx, dy = math.cos(th + a), math.sin(th + a)
            ix, iy = math.floor(px), math.floor(py)
            sx, tdx, tmx = _axis_setup(px, dx)
            sy, tdy, tmy = _axis_setup(py, dy)
            limit = max_range / res
            t, hit = 0.0, max_range
            while t <= limit:
                if ix < 0 or ix >= w or iy < 0 or iy >= h:
                    break
                if occ[iy, ix]:
                    hit = t * res
                    break
                if tmx < tmy:
                    t, ix, tmx = tmx, ix + sx, tmx + tdx
                else:
                    t, iy, tmy = tmy, iy + sy, tmy + tdy
            out[p, b] = min(hit, max_range)
    return out


def old_walk(gx, gy, dx, dy, length, w, h):
    """``mapping._map_kernels._walk`` before the merge: cells and entry ranges of a ray."""
    ix, iy = math.floor(gx), math.floor(gy)
    sx, tdx, tmx = _axis_setup(gx, dx)
    sy, tdy, tmy = _axis_setup(gy, dy)
    cells, dists = [], []
    t = 0.0
    while t < length:
        if 0 <= ix < w and 0 <= iy < h:
            cells.append(iy * w + ix)
            dists.append(t)
        if tmx < tmy:
            t, tmx, ix = tmx, tmx + tdx, ix + sx
        else:
            t, tmy, iy = tmy, tmy + tdy, iy + sy
    return cells, dists


def _random_world(seed):
    rng = np.random.default_rng(seed)
    occ = rng.random((50, 70)) < 0.04
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    spec = GridSpec(0.1, (-2.0, -1.5), occ.shape)
    poses = np.column_stack(
        [rng.uniform(-2.5, 5.5, 25), rng.uniform(-2.0, 4.0, 25), rng.uniform(-4, 4, 25)]
    )
    return rng, occ, spec, poses


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_grid_ray_caster_equals_the_old_loop(seed):
    _, occ, spec, poses = _random_world(seed)
    angles = np.linspace(-np.pi, np.pi, 73)
    for max_range in (0.7, 3.0, 20.0):
        new = cast_rays(occ, spec, poses, angles, max_range)
        old = old_cast_rays(occ, *spec.origin, spec.resolution, poses, angles, max_range)
        np.testing.assert_array_equal(new, old)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ray_cells_equal_the_old_map_walk(seed):
    rng = np.random.default_rng(seed)
    w, h = 40, 30
    for _ in range(200):
        gx, gy = rng.uniform(-5, 45), rng.uniform(-5, 35)
        a = rng.uniform(-4, 4)
        dx, dy = math.cos(a), math.sin(a)
        if rng.random() < 0.1:  # axis-aligned rays: one direction component exactly 0
            dx, dy = (1.0, 0.0) if rng.random() < 0.5 else (0.0, -1.0)
        length = rng.uniform(0, 30)
        cells = np.empty(200, np.int64)
        dists = np.empty(200)
        n = T.ray_cells(gx, gy, dx, dy, length, w, h, cells, dists, 0)
        ref_cells, ref_dists = old_walk(gx, gy, dx, dy, length, w, h)
        assert cells[:n].tolist() == ref_cells
        assert dists[:n].tolist() == ref_dists


def test_cast_exact_stops_where_ray_cells_meets_the_first_occupied_cell():
    """The caster and the cell list are one walk: the range to the first occupied cell is the
    entry range of that cell in the list, to the last bit."""
    rng, occ, _, _ = _random_world(3)
    h, w = occ.shape
    cells = np.empty(500, np.int64)
    dists = np.empty(500)
    for _ in range(300):
        gx, gy, a = rng.uniform(1, w - 1), rng.uniform(1, h - 1), rng.uniform(-4, 4)
        dx, dy = math.cos(a), math.sin(a)
        t = T.cast_exact(occ, gx, gy, dx, dy, 200.0)
        n = T.ray_cells(gx, gy, dx, dy, 200.0, w, h, cells, dists, 0)
        first = [k for k in range(n) if occ.flat[cells[k]]][0]  # the border is occupied
        assert t == dists[first]


def test_beam_model_exact_casting_equals_the_grid_caster():
    """BeamModel's exact caster and grid.raycast.cast_rays call the same kernel."""
    _, occ, spec, poses = _random_world(4)
    angles = np.linspace(-np.pi, np.pi, 41)
    bm = BeamModel(spec, occ, max_range=4.0, ray_casting="exact")
    inside = (poses[:, 0] > -2.0) & (poses[:, 0] < 4.9) & (poses[:, 1] > -1.5) & (poses[:, 1] < 3.4)
    got = bm.expected_ranges(poses[inside], angles)
    ref = cast_rays(occ, spec, poses[inside], angles, 4.0)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)


def test_segment_walk_counts_cells_and_ends_in_the_last_cell():
    rng = np.random.default_rng(6)
    for _ in range(500):
        g = rng.uniform(-20, 20, 4)
        ix, iy, ex, ey, sx, sy, tmx, tmy, tdx, tdy, n = T.walk_start(*g, True)
        assert n == abs(ex - ix) + abs(ey - iy) + 1
        seen = [(ix, iy)]
        for _ in range(n - 1):
            ix, iy, tmx, tmy = T.walk_next(ix, iy, ex, ey, sx, sy, tmx, tmy, tdx, tdy)
            seen.append((ix, iy))
        assert seen[0] == (math.floor(g[0]), math.floor(g[1]))
        assert seen[-1] == (math.floor(g[2]), math.floor(g[3]))
        # 4-connected: every step moves to a neighbour
        steps = np.abs(np.diff(np.array(seen), axis=0)).sum(axis=1)
        assert np.all(steps == 1)
