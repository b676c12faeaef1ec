"""Submaps of graph SLAM: the incremental splat kernel against a numpy reference and against the
full field, the incrementally kept field of an active submap, and what a finished submap keeps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from probmap.grid.occupancy import InverseSensorModel, OccupancyGrid
from probmap.grid.raycast import cast_rays
from probmap.grid.spec import GridSpec
from probmap.slam.laser import _match_kernels as K
from probmap.slam.laser.scan_matching import MatchField
from probmap.slam.laser.submaps import Submap, angular_search_step, match_field_from_occupied_cells

RES = 0.05
SIGMA = 0.05
RADIUS = 3
INV = 0.5 * (RES / SIGMA) ** 2  # 1 / (2 sigma^2) in cells^-2


def splat_reference(field, iys, ixs, radius, inv):
    """Raise ``field`` to ``exp(-d^2 inv)`` within ``radius`` cells of each cell (slow, plain)."""
    out = field.copy()
    h, w = out.shape
    yy, xx = np.mgrid[0:h, 0:w]
    for iy, ix in zip(iys, ixs, strict=True):
        d2 = (yy - iy) ** 2 + (xx - ix) ** 2
        kern = np.where(d2 <= radius * radius, np.exp(-d2 * inv), 0.0)
        out = np.maximum(out, kern)
    return out


def field_reference(lo, radius, inv):
    """The match field of a log-odds image: the kernel of the nearest occupied cell."""
    iys, ixs = np.nonzero(lo > 0)
    return splat_reference(np.zeros(lo.shape), iys, ixs, radius, inv)


# ----------------------------------------------------------------- the kernel
@pytest.mark.parametrize("radius", [0, 1, 3, 5])
def test_splat_cells_matches_numpy_reference(radius):
    rng = np.random.default_rng(radius)
    h, w = 23, 31
    start = rng.uniform(0.0, 0.6, (h, w))  # values the max rule must keep where larger
    # cells inside, on the border and in the corners (the kernel is clipped there)
    iys = np.concatenate([rng.integers(0, h, 12), [0, h - 1, 0, h - 1]]).astype(np.int64)
    ixs = np.concatenate([rng.integers(0, w, 12), [0, w - 1, w - 1, 0]]).astype(np.int64)
    out = start.copy()
    K.splat_cells(iys, ixs, radius, INV, out)
    expect = splat_reference(start, iys, ixs, radius, INV)
    np.testing.assert_allclose(out, expect, rtol=1e-15, atol=0)
    # the kernel raised some values and kept the larger old ones
    assert (out > start).any() and (out == start).any()


def test_splat_cells_of_occupied_cells_equals_splat_field():
    rng = np.random.default_rng(1)
    lo = rng.normal(-1.0, 1.0, (40, 50)).astype(np.float32)  # about 16 % of cells occupied
    iys, ixs = np.nonzero(lo > 0)
    assert 100 < len(iys) < 1000
    out = np.zeros(lo.shape)
    K.splat_cells(iys.astype(np.int64), ixs.astype(np.int64), RADIUS, INV, out)
    full = np.empty(lo.shape)
    K.splat_field(lo, 0.0, RADIUS, INV, full)
    np.testing.assert_array_equal(out, full)  # same kernel, same max rule: bit for bit
    np.testing.assert_allclose(full, field_reference(lo, RADIUS, INV), rtol=1e-15, atol=0)


def test_splat_cells_in_any_order_and_split_equals_one_call():
    rng = np.random.default_rng(2)
    iys = rng.integers(0, 30, 60).astype(np.int64)
    ixs = rng.integers(0, 30, 60).astype(np.int64)
    one = np.zeros((30, 30))
    K.splat_cells(iys, ixs, RADIUS, INV, one)
    parts = np.zeros((30, 30))
    order = rng.permutation(60)
    K.splat_cells(iys[order[:25]], ixs[order[:25]], RADIUS, INV, parts)
    K.splat_cells(iys[order[25:]], ixs[order[25:]], RADIUS, INV, parts)
    np.testing.assert_array_equal(one, parts)


# ----------------------------------------------------------------- fields of occupied cells
def test_match_field_from_occupied_cells_equals_the_field_of_the_grid():
    rng = np.random.default_rng(3)
    spec = GridSpec(RES, (-1.3, 0.45), (37, 44))
    occ = rng.random(spec.shape) < 0.03
    cells = np.flatnonzero(occ).astype(np.int64)
    fld = match_field_from_occupied_cells(cells, spec, SIGMA, RADIUS)
    assert fld.values.shape == spec.shape
    assert fld.origin == spec.origin and fld.resolution == RES
    # bit for bit the splat kernel over the same grid
    full = np.empty(spec.shape)
    K.splat_field(occ.astype(np.float32), 0.0, RADIUS, INV, full)
    np.testing.assert_array_equal(fld.values, full)
    # and the exact distance-transform field wherever the nearest occupied cell is within the
    # radius (0 beyond it)
    from scipy.ndimage import distance_transform_edt

    exact = MatchField.from_occupied(occ, spec, SIGMA)
    near = distance_transform_edt(~occ) <= RADIUS
    assert near.any() and (~near).any()
    np.testing.assert_allclose(fld.values[near], exact.values[near], rtol=1e-12)
    assert not fld.values[~near].any()


def test_match_field_of_no_cells_is_zero():
    spec = GridSpec(RES, (0.0, 0.0), (5, 7))
    fld = match_field_from_occupied_cells(np.zeros(0, dtype=np.int64), spec, SIGMA, RADIUS)
    assert fld.values.shape == (5, 7) and not fld.values.any()


# ----------------------------------------------------------------- submaps over a simulated room
def _room():
    """A 6 x 4 m room with a pillar and a box that a later scan sees through (a door)."""
    spec = GridSpec(RES, (0.0, 0.0), (80, 120))
    occ = np.zeros(spec.shape, dtype=bool)
    occ[:3, :] = occ[-3:, :] = True
    occ[:, :3] = occ[:, -3:] = True
    occ[30:36, 60:66] = True  # pillar
    return occ, spec


def _scans(occ, spec, poses, n_beams=181, max_range=8.0):
    angles = np.linspace(-math.pi / 2, math.pi / 2, n_beams)
    ranges = cast_rays(occ, spec, np.asarray(poses), angles, max_range)
    return ranges, angles


def _model():
    return InverseSensorModel(0.7, 0.4, max_clear_range=0.0)


def _field_of(grid):
    out = np.empty(grid.log_odds.shape)
    K.splat_field(grid.log_odds, 0.0, RADIUS, INV, out)
    return out


def _incremental_against_full(ranges, angles, poses):
    """Insert scans one by one into a submap whose field was built after the first; while no
    occupied cell has been freed, compare the kept field with a full recomputation. Returns the
    number of inserts compared."""
    sm = Submap(0, 0, RES, SIGMA, RADIUS, _model())
    sm.insert(0, poses[0], ranges[0], angles, 8.0)
    sm.field()  # build it; later inserts keep it up to date
    checked = 0
    for k in range(1, len(poses)):
        assert sm.grid is not None
        before_spec = sm.grid.spec
        before = sm.grid.log_odds > 0
        sm.insert(k, poses[k], ranges[k], angles, 8.0)
        if sm.grid.spec != before_spec:  # the grid grew: the field is rebuilt on demand
            assert sm._field is None
            sm.field()
            continue
        if (before & ~(sm.grid.log_odds > 0)).any():
            break  # a cell was freed: the claim no longer applies (see the next tests)
        assert sm._field is not None  # kept, not rebuilt
        np.testing.assert_array_equal(sm._field.values, _field_of(sm.grid))
        checked += 1
    return checked


POSES = np.array(
    [[1.0, 1.0, 0.3], [1.5, 1.2, 0.6], [2.0, 1.0, 1.0], [2.2, 2.8, -0.5], [4.8, 3.0, -2.5]]
)


def test_incremental_field_equals_recomputation_when_no_cell_is_freed():
    occ, spec = _room()
    ranges, angles = _scans(occ, spec, POSES)
    # range noise: no endpoint lies on a cell boundary (see the next test for those)
    ranges = ranges + np.random.default_rng(4).normal(0.0, 0.01, ranges.shape)
    assert _incremental_against_full(ranges, angles, POSES) >= 2


def test_incremental_field_equals_recomputation_with_endpoints_on_cell_boundaries():
    occ, spec = _room()
    ranges, angles = _scans(occ, spec, POSES)  # exact ray casting: endpoints on cell edges
    assert _incremental_against_full(ranges, angles, POSES) >= 2


def test_field_is_recomputed_every_refresh_every_inserts_and_then_exact():
    occ, spec = _room()
    ranges_in, angles = _scans(occ, spec, [[1.0, 2.0, 0.0]])
    # an obstacle that is there for the first scans and gone later: its cells get freed
    blocked = occ.copy()
    blocked[36:44, 40:43] = True
    pose = np.array([1.0, 2.0, 0.0])
    r_block, _ = _scans(blocked, spec, [pose])
    sm = Submap(0, 0, RES, SIGMA, RADIUS, _model())
    sm.insert(0, pose, r_block[0], angles, 8.0)
    sm.insert(1, pose, r_block[0], angles, 8.0)
    built = sm.field()
    assert sm._since_refresh == 0
    n = Submap.refresh_every
    for k in range(2, 2 + n - 1):
        sm.insert(k, pose, ranges_in[0], angles, 8.0)
    assert sm.grid is not None
    obstacle = np.zeros(sm.grid.log_odds.shape, dtype=bool)
    # cells of the obstacle in the submap grid (same lattice, origin may differ)
    ox = round(sm.grid.spec.origin[0] / RES)
    oy = round(sm.grid.spec.origin[1] / RES)
    obstacle[36 - oy : 44 - oy, 40 - ox : 43 - ox] = True
    freed = obstacle & (sm.grid.log_odds <= 0)
    assert freed.any()  # the obstacle's cells are free now ...
    stale = sm.field()
    assert stale is built  # ... but the kept field still holds them (documented)
    fresh = _field_of(sm.grid)
    assert (stale.values[freed] > fresh[freed]).all()
    # the refresh_every-th insert since the full computation triggers a new one: exact again
    sm.insert(2 + n - 1, pose, ranges_in[0], angles, 8.0)
    assert sm._field is None
    np.testing.assert_array_equal(sm.field().values, _field_of(sm.grid))


def test_finish_keeps_exactly_the_occupied_cells_and_the_same_field():
    occ, spec = _room()
    poses = np.array([[1.0, 1.0, 0.3], [2.0, 2.0, 0.9], [4.0, 3.0, -2.0], [5.0, 1.0, 2.5]])
    ranges, angles = _scans(occ, spec, poses)
    sm = Submap(3, 17, RES, SIGMA, RADIUS, _model())
    for k, p in enumerate(poses):
        sm.insert(17 + k, p, ranges[k], angles, 8.0)
    assert sm.grid is not None
    grid: OccupancyGrid = sm.grid
    g_spec = grid.spec
    iy, ix = np.nonzero(grid.log_odds > 0)
    world_before = {tuple(v) for v in np.round(g_spec.cell_to_world(np.column_stack([ix, iy])), 9)}
    field_before = _field_of(grid)
    np.testing.assert_allclose(sm.centre, poses[:, :2].mean(axis=0))
    sm.finish()
    assert sm.finished and sm.grid is None and sm.size == 4 and sm.nodes == [17, 18, 19, 20]
    assert sm.occupied_cells() == len(world_before)
    f = sm.field()
    fs = GridSpec(RES, f.origin, f.values.shape)
    cells = np.flatnonzero(f.values == 1.0)  # an occupied cell has field exactly 1
    xy = fs.cell_to_world(np.column_stack([cells % fs.width, cells // fs.width]))
    assert {tuple(v) for v in np.round(xy, 9)} == world_before
    # the finished field is the active one cropped (margin keeps every kernel whole)
    dx = round((f.origin[0] - g_spec.origin[0]) / RES)
    dy = round((f.origin[1] - g_spec.origin[1]) / RES)
    h, w = f.values.shape
    np.testing.assert_array_equal(f.values, field_before[dy : dy + h, dx : dx + w])
    assert np.isclose(field_before.sum(), f.values.sum())  # nothing non-zero was cropped away
    # radius: the farthest inserted pose from the centre
    assert sm.radius == pytest.approx(np.hypot(*(poses[:, :2] - sm.centre).T).max())
    # released and rebuilt on demand, equal; a finished submap refuses inserts
    sm.release()
    np.testing.assert_array_equal(sm.field().values, f.values)
    with pytest.raises(RuntimeError, match="finished"):
        sm.insert(99, poses[0], ranges[0], angles, 8.0)


def test_angular_search_step_moves_the_farthest_point_one_cell():
    step = angular_search_step(0.05, 30.0)
    # chord of the farthest point equals one cell
    assert 2 * 30.0 * math.sin(step / 2) == pytest.approx(0.05, rel=1e-9)
    assert angular_search_step(0.05, 0.0) == pytest.approx(math.pi / 3)  # clamped to one cell
