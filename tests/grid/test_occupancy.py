"""Tests of the log-odds occupancy grid against closed forms and a pure-Python reference."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from probmap.grid.logodds import logit, prob
from probmap.grid.occupancy import GridBoundsError, InverseSensorModel, OccupancyGrid
from probmap.grid.spec import GridSpec
from probmap.metrics.map import map_accuracy
from probmap.sim.floorplan import simulate_laser_world

# --------------------------------------------------------------------------- reference


def segment_cells(gx0, gy0, gx1, gy1):
    """Cells whose square meets the segment, ordered along it (independent of the kernel's walk).

    Every cell in the bounding box is clipped against the segment (Liang-Barsky); the cells with a
    non-empty intersection are sorted by the parameter at which the segment enters them.
    """
    cells = []
    for ix in range(math.floor(min(gx0, gx1)), math.floor(max(gx0, gx1)) + 1):
        for iy in range(math.floor(min(gy0, gy1)), math.floor(max(gy0, gy1)) + 1):
            t0, t1 = 0.0, 1.0
            ok = True
            for p, q in (
                (-(gx1 - gx0), gx0 - ix),
                (gx1 - gx0, ix + 1 - gx0),
                (-(gy1 - gy0), gy0 - iy),
                (gy1 - gy0, iy + 1 - gy0),
            ):
                if p == 0:
                    if q < 0:
                        ok = False
                        break
                    continue
                r = q / p
                if p < 0:
                    t0 = max(t0, r)
                else:
                    t1 = min(t1, r)
            if ok and t0 <= t1:
                cells.append((t0, ix, iy))
    cells.sort()
    return [(ix, iy) for _, ix, iy in cells]


def reference_integrate(
    lo, sid_stamp, spec, poses, ranges, angles, max_range, model, l0, lmin, lmax
):
    """Slow reference of the binary Bayes filter update with the once-per-scan rule."""
    ox, oy = spec.origin
    inv = 1.0 / spec.resolution
    clear = max_range if model.max_clear_range is None else model.max_clear_range
    d_hit = model.l_hit - l0
    d_free = model.l_miss - l0
    for s in range(len(poses)):
        px, py, th = poses[s]
        gx0, gy0 = (px - ox) * inv, (py - oy) * inv
        hits, free = set(), set()
        for r, a in zip(ranges[s], angles, strict=True):
            if not (r > 0) or not math.isfinite(r):
                continue
            c, sn = math.cos(th + a), math.sin(th + a)
            if r >= max_range:
                if clear <= 0:
                    continue
                ex, ey = (px + clear * c - ox) * inv, (py + clear * sn - oy) * inv
            else:
                ex, ey = (px + r * c - ox) * inv, (py + r * sn - oy) * inv
                tx = (px + (r + model.thickness) * c - ox) * inv
                ty = (py + (r + model.thickness) * sn - oy) * inv
                hits.update(segment_cells(ex, ey, tx, ty))
            free.update(segment_cells(gx0, gy0, ex, ey)[:-1])
        for cells, d in ((hits, d_hit), (free - hits, d_free)):
            for ix, iy in cells:
                v = float(lo[iy, ix]) + d
                lo[iy, ix] = min(max(v, lmin), lmax)
                sid_stamp[iy, ix] = True


def random_scans(rng, n_scans, n_beams, spread=3.0):
    poses = np.column_stack(
        [
            rng.uniform(-1, 1, n_scans),
            rng.uniform(-1, 1, n_scans),
            rng.uniform(-np.pi, np.pi, n_scans),
        ]
    )
    ranges = rng.uniform(0.05, spread, (n_scans, n_beams))
    ranges[rng.random(ranges.shape) < 0.05] = np.nan
    ranges[rng.random(ranges.shape) < 0.05] = -1.0
    ranges[rng.random(ranges.shape) < 0.1] = spread + 1.0  # max-range readings
    angles = np.sort(rng.uniform(-np.pi, np.pi, n_beams))
    return poses, ranges, angles


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("thickness,clear", [(0.0, None), (0.12, 1.5), (0.0, 0.0)])
def test_kernel_matches_reference(seed, thickness, clear):
    rng = np.random.default_rng(seed)
    res = float(rng.choice([0.05, 0.1, 0.23]))
    poses, ranges, angles = random_scans(rng, 5, 40)
    max_range = 3.0 + 0.5
    model = InverseSensorModel(p_hit=0.7, p_miss=0.4, thickness=thickness, max_clear_range=clear)
    spec = GridSpec(res, (-6.0, -6.5), (int(13 / res), int(12 / res)))
    grid = OccupancyGrid(res, p0=0.45, model=model, spec=spec, fixed=True)
    grid.integrate_scans(poses, ranges, angles, max_range=max_range)

    lo = np.full(spec.shape, grid.l0, dtype=np.float32)
    seen = np.zeros(spec.shape, bool)
    reference_integrate(
        lo, seen, spec, poses, ranges, angles, max_range, model, grid.l0, grid.l_min, grid.l_max
    )
    np.testing.assert_array_equal(grid.observed, seen)
    np.testing.assert_array_equal(grid.log_odds, lo)


@pytest.mark.parametrize("batched", [True, False])
def test_one_byte_stamp_across_epochs_matches_reference(batched):
    # 600 scans cross the 254-scan epochs of the one-byte stamp twice, in one batch and one
    # scan at a time: every cell still changes at most once per scan, as in the reference
    rng = np.random.default_rng(11)
    poses, ranges, angles = random_scans(rng, 600, 12, spread=1.5)
    poses[:, :2] *= 0.3  # many scans over the same cells
    model = InverseSensorModel(p_hit=0.7, p_miss=0.45, thickness=0.1, max_clear_range=1.0)
    spec = GridSpec(0.1, (-3.0, -3.0), (60, 60))
    grid = OccupancyGrid(0.1, model=model, spec=spec, fixed=True, clamp=(0.001, 0.999))
    if batched:
        grid.integrate_scans(poses, ranges, angles, max_range=2.0)
    else:
        for p, r in zip(poses, ranges, strict=True):
            grid.integrate_scan(p, r, angles, max_range=2.0)
    lo = np.full(spec.shape, grid.l0, dtype=np.float32)
    seen = np.zeros(spec.shape, bool)
    reference_integrate(
        lo, seen, spec, poses, ranges, angles, 2.0, model, grid.l0, grid.l_min, grid.l_max
    )
    assert grid.scans_integrated == 600
    np.testing.assert_array_equal(grid.observed, seen)
    np.testing.assert_allclose(grid.log_odds, lo, rtol=0, atol=2e-5)
    assert grid._stamp.dtype == np.uint8  # one byte per cell


def test_walk_cells_are_exact_on_random_segments():
    """The kernel's cells for one beam equal the cells whose squares the segment meets."""
    rng = np.random.default_rng(7)
    for _ in range(200):
        res = 0.1
        spec = GridSpec(res, (-5.0, -5.0), (100, 100))
        grid = OccupancyGrid(res, spec=spec, fixed=True)
        x, y, th = rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(-np.pi, np.pi)
        r = rng.uniform(0.01, 2.5)
        grid.integrate_scan([x, y, th], [r], [0.0], max_range=10.0)
        got = set(zip(*np.nonzero(grid.observed)[::-1], strict=True))
        want = segment_cells(
            (x + 5) / res,
            (y + 5) / res,
            (x + r * math.cos(th) + 5) / res,
            (y + r * math.sin(th) + 5) / res,
        )
        assert got == set(want)


def test_update_is_the_log_odds_recursion():
    """l_t = l_{t-1} + inverse_model - l0, with p = 1 - 1/(1+exp(l)) (Table 4.2)."""
    model = InverseSensorModel(p_hit=0.8, p_miss=0.3)
    grid = OccupancyGrid(0.1, p0=0.4, clamp=(0.001, 0.999), model=model)
    for _ in range(3):
        grid.integrate_scan([0.0, 0.0, 0.0], [1.0], [0.0], max_range=5.0)
    l0 = logit(0.4)
    end = grid.spec.world_to_cell([1.05, 0.0])
    mid = grid.spec.world_to_cell([0.55, 0.0])
    lo = grid.log_odds
    assert lo[end[1], end[0]] == pytest.approx(l0 + 3 * (logit(0.8) - l0), abs=1e-6)
    assert lo[mid[1], mid[0]] == pytest.approx(l0 + 3 * (logit(0.3) - l0), abs=1e-6)
    p = grid.probability()[end[1], end[0]]
    assert p == pytest.approx(1 - 1 / (1 + math.exp(l0 + 3 * (logit(0.8) - l0))), abs=1e-6)


def test_once_per_scan_and_hit_wins():
    grid = OccupancyGrid(0.1, spec=GridSpec(0.1, (-2.0, -2.0), (40, 40)), fixed=True)
    # 50 beams through the same cells in one scan: each cell changes once
    grid.integrate_scan([0.0, 0.0, 0.0], np.full(50, 1.0), np.zeros(50), max_range=5.0)
    end = grid.spec.world_to_cell([1.05, 0.0])
    mid = grid.spec.world_to_cell([0.55, 0.0])
    assert grid.log_odds[end[1], end[0]] == pytest.approx(logit(0.7), abs=1e-6)
    assert grid.log_odds[mid[1], mid[0]] == pytest.approx(logit(0.4), abs=1e-6)
    # one beam ends at x=0.55, another crosses it on the way to x=1.5: the hit wins
    g2 = OccupancyGrid(0.1, spec=GridSpec(0.1, (-2.0, -2.0), (40, 40)), fixed=True)
    g2.integrate_scan([0.0, 0.0, 0.0], [1.5, 0.55], [0.0, 0.0], max_range=5.0)
    assert g2.log_odds[mid[1], mid[0]] == pytest.approx(logit(0.7), abs=1e-6)
    # ...whatever the beam order
    g3 = OccupancyGrid(0.1, spec=GridSpec(0.1, (-2.0, -2.0), (40, 40)), fixed=True)
    g3.integrate_scan([0.0, 0.0, 0.0], [0.55, 1.5], [0.0, 0.0], max_range=5.0)
    np.testing.assert_array_equal(g2.log_odds, g3.log_odds)


def test_clamping_bounds():
    grid = OccupancyGrid(0.1)
    for _ in range(40):
        grid.integrate_scan([0.0, 0.0, 0.0], [1.0], [0.0], max_range=5.0)
    end = grid.spec.world_to_cell([1.05, 0.0])
    mid = grid.spec.world_to_cell([0.55, 0.0])
    assert grid.probability()[end[1], end[0]] == pytest.approx(0.97, abs=1e-6)
    assert grid.probability()[mid[1], mid[0]] == pytest.approx(0.12, abs=1e-6)


def test_max_range_and_dropped_readings():
    model = InverseSensorModel(max_clear_range=2.0)
    grid = OccupancyGrid(0.1, model=model, spec=GridSpec(0.1, (-5.0, -5.0), (100, 100)), fixed=True)
    stats = grid.integrate_scan(
        [0.0, 0.0, 0.0], [5.0, 7.0, np.nan, np.inf, 0.0, -1.0, 1.0], np.zeros(7), max_range=5.0
    )
    assert (stats.hits, stats.max_range, stats.dropped) == (1, 2, 4)
    beyond = grid.spec.world_to_cell([2.5, 0.0])
    assert not grid.observed[beyond[1], beyond[0]]
    assert grid.log_odds.max() == pytest.approx(logit(0.7), abs=1e-6)
    # max-range readings alone never create an occupied cell and clear up to 2 m
    g2 = OccupancyGrid(0.1, model=model)
    g2.integrate_scan([0.0, 0.0, 0.0], [5.0], [0.0], max_range=5.0)
    assert g2.log_odds.max() <= 0
    assert g2.observed.sum() == 20


def test_growth_keeps_world_positions_and_is_amortised():
    grid = OccupancyGrid(0.1)
    grid.integrate_scan([0.0, 0.0, 0.0], [1.03], [0.0], max_range=5.0)
    shapes = {grid.spec.shape}
    for k in range(1, 400):
        grid.integrate_scan([0.5 * k, 0.3 * k + 0.013, 0.0], [1.03], [0.0], max_range=5.0)
        shapes.add(grid.spec.shape)
    assert len(shapes) < 20  # geometric growth, not per scan
    # the very first hit is still where it was in the world
    end = grid.spec.world_to_cell([1.03, 0.0])
    assert grid.log_odds[end[1], end[0]] == pytest.approx(logit(0.7), abs=1e-6)
    last = grid.spec.world_to_cell([0.5 * 399 + 1.03, 0.3 * 399 + 0.013])
    assert grid.log_odds[last[1], last[0]] == pytest.approx(logit(0.7), abs=1e-6)


def test_fixed_grid_raises():
    grid = OccupancyGrid(0.1, spec=GridSpec(0.1, (0.0, 0.0), (10, 10)), fixed=True)
    with pytest.raises(GridBoundsError, match="outside the fixed grid"):
        grid.integrate_scan([0.5, 0.5, 0.0], [3.0], [0.0], max_range=5.0)
    assert not grid.observed.any()


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(pose=[0, 0], ranges=[1.0], angles=[0.0]), "pose must have shape"),
        (dict(pose=[0, 0, 0], ranges=[[1.0]], angles=[0.0]), "ranges must be 1-D"),
        (dict(pose=[0, 0, 0], ranges=[1.0, 2.0], angles=[0.0]), "angles shape"),
        (dict(pose=[0, 0, np.nan], ranges=[1.0], angles=[0.0]), "finite"),
    ],
)
def test_bad_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        OccupancyGrid(0.1).integrate_scan(**kwargs, max_range=5.0)


def test_bad_parameters():
    with pytest.raises(ValueError, match="p_hit"):
        InverseSensorModel(p_hit=1.2)
    with pytest.raises(ValueError, match="clamp"):
        OccupancyGrid(0.1, clamp=(0.6, 0.9))
    with pytest.raises(ValueError, match="resolution"):
        OccupancyGrid(-0.1)


def test_logit_prob_closed_form():
    p = np.linspace(0.01, 0.99, 99)
    np.testing.assert_allclose(prob(logit(p)), p, rtol=1e-12)
    l = np.linspace(-30, 30, 61)
    np.testing.assert_allclose(prob(l), 1 - 1 / (1 + np.exp(l)), atol=1e-15)
    with pytest.raises(ValueError):
        logit(1.0)


def test_classify_trinary():
    grid = OccupancyGrid(0.1)
    for _ in range(5):
        grid.integrate_scan([0.0, 0.0, 0.0], [1.0], [0.0], max_range=5.0)
    c = grid.classify()
    end = grid.spec.world_to_cell([1.05, 0.0])
    mid = grid.spec.world_to_cell([0.55, 0.0])
    assert c[end[1], end[0]] == 1 and c[mid[1], mid[0]] == 0
    assert (c[~grid.observed] == -1).all()


@pytest.mark.parametrize("seed", [0, 1])
def test_simulated_world_accuracy(seed):
    world = simulate_laser_world(seed=seed, range_noise=0.02, dropout=0.01)
    grid = OccupancyGrid(0.05)
    grid.integrate_scans(world.poses, world.ranges, world.angles, max_range=world.max_range)
    acc, n = map_accuracy(grid.classify(0.5, 0.5), grid.spec, world.truth, world.spec)
    print(f"seed {seed}: {acc:.4f} of {n} observed cells classified correctly")
    assert n > 50_000
    assert acc >= 0.98


def test_cropped_keeps_world_positions():
    grid = OccupancyGrid(0.1)
    grid.integrate_scan([3.0, 2.0, 0.3], [1.03, 2.07], [0.0, 0.5], max_range=5.0)
    grid._ensure_bounds(np.array([-40.0, 40.0, -40.0, 40.0]))  # unobserved border
    small = grid.cropped(margin=1)
    assert small.spec.width < grid.spec.width and small.spec.height < grid.spec.height
    assert small.observed.sum() == grid.observed.sum()
    iy, ix = np.nonzero(grid.observed)
    world = grid.spec.cell_to_world(np.column_stack([ix, iy]))
    c = small.spec.world_to_cell(world)
    np.testing.assert_array_equal(small.log_odds[c[:, 1], c[:, 0]], grid.log_odds[iy, ix])


def test_max_range_clearing_never_passes_the_sensor_range():
    model = InverseSensorModel(max_clear_range=10.0)
    grid = OccupancyGrid(0.1, model=model)
    grid.integrate_scan([0.0, 0.0, 0.0], [4.0], [0.0], max_range=4.0)
    assert grid.observed.sum() == 40  # 4 m of free cells, not 10


# --------------------------------------------------------------------------- per-scan fast path


class _CountGeneral:
    """Counts the calls of ``OccupancyGrid.integrate_scans`` (the general path)."""

    def __init__(self, monkeypatch):
        self.calls = 0
        general = OccupancyGrid.integrate_scans

        def spy(grid, *args, **kwargs):
            self.calls += 1
            return general(grid, *args, **kwargs)

        monkeypatch.setattr(OccupancyGrid, "integrate_scans", spy)


def _state(grid):
    return grid.spec, grid.log_odds.copy(), grid._stamp.copy(), grid._sid, grid.scans_integrated


def _assert_same_state(a, b):
    assert a[0] == b[0]
    np.testing.assert_array_equal(a[1], b[1])
    np.testing.assert_array_equal(a[2], b[2])
    assert a[3:] == b[3:]


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("thickness,clear", [(0.0, None), (0.12, 1.5), (0.0, 0.0), (0.07, 9.0)])
def test_single_scan_fast_path_matches_batch_and_reference(monkeypatch, seed, thickness, clear):
    rng = np.random.default_rng(100 + seed)
    res = float(rng.choice([0.05, 0.1, 0.23]))
    poses, ranges, angles = random_scans(rng, 12, int(rng.integers(1, 60)))
    ranges[0, :] = np.inf  # a scan with no valid reading
    max_range = 3.5
    model = InverseSensorModel(p_hit=0.72, p_miss=0.38, thickness=thickness, max_clear_range=clear)
    spec = GridSpec(res, (-6.0, -6.5), (int(13 / res), int(12 / res)))

    def make():
        return OccupancyGrid(res, p0=0.45, model=model, spec=spec, fixed=True)

    batch = make()
    total = batch.integrate_scans(poses, ranges, angles, max_range=max_range)
    single = make()
    spy = _CountGeneral(monkeypatch)
    stats = [
        single.integrate_scan(p, r, angles, max_range=max_range)
        for p, r in zip(poses, ranges, strict=True)
    ]
    assert spy.calls == 0  # every scan took the compiled single-scan path
    assert sum(stats[1:], stats[0]) == total
    assert all(s.scans == 1 and s.beams == len(angles) for s in stats)
    _assert_same_state(_state(single), _state(batch))

    lo = np.full(spec.shape, single.l0, dtype=np.float32)
    seen = np.zeros(spec.shape, bool)
    # the reference clears max-range readings up to max_clear_range itself: cap it as the grid does
    capped = model if clear is None else replace(model, max_clear_range=min(clear, max_range))
    reference_integrate(
        lo, seen, spec, poses, ranges, angles, max_range, capped, single.l0, single.l_min,
        single.l_max,
    )  # fmt: skip
    np.testing.assert_array_equal(single.log_odds, lo)
    np.testing.assert_array_equal(single.observed, seen)


def test_single_scan_fast_path_epochs_and_unusual_arrays(monkeypatch):
    # 600 scans one at a time cross two epochs of the one-byte stamp: the scan that starts a
    # new epoch takes the general path, and the stamps equal those of the batch path; lists,
    # integers, strided views and read-only arrays give the same map
    rng = np.random.default_rng(5)
    poses, ranges, angles = random_scans(rng, 600, 9, spread=1.5)
    poses[:, :2] *= 0.3
    spec = GridSpec(0.1, (-3.0, -3.0), (60, 60))
    batch = OccupancyGrid(0.1, spec=spec, fixed=True, clamp=(0.001, 0.999))
    batch.integrate_scans(poses, ranges, angles, max_range=2.0)
    single = OccupancyGrid(0.1, spec=spec, fixed=True, clamp=(0.001, 0.999))
    frozen = angles.copy()
    frozen.flags.writeable = False
    spy = _CountGeneral(monkeypatch)
    for k in range(600):
        if k % 4 == 0:
            single.integrate_scan(poses[k].tolist(), ranges[k].tolist(), list(angles), max_range=2)
        elif k % 4 == 1:
            wide = np.repeat(ranges[k], 2)[::2]  # not contiguous
            single.integrate_scan(poses[k], wide, frozen, max_range=np.float32(2.0))
        else:
            single.integrate_scan(poses[k], ranges[k], angles, max_range=2.0)
    assert spy.calls == 2  # scans 255 and 509 start the second and third epochs
    _assert_same_state(_state(single), _state(batch))
    # per-scan angles of shape (1, B) are accepted, by the general path
    single.integrate_scan(poses[0], ranges[0], angles[None, :], max_range=2.0)
    assert spy.calls == 3
    batch.integrate_scans(poses[:1], ranges[:1], angles[None, :], max_range=2.0)
    _assert_same_state(_state(single), _state(batch))


@pytest.mark.parametrize(
    "pose,ranges,angles,max_range,error",
    [
        ([0.0, np.nan, 0.0], [1.0, 2.0], [0.0, 0.1], 5.0, "poses must be finite numbers; pose 0"),
        ([0.0, 0.0, np.inf], [1.0, 2.0], [0.0, 0.1], 5.0, "poses must be finite numbers; pose 0"),
        ([0.0, 0.0], [1.0, 2.0], [0.0, 0.1], 5.0, "pose must have shape"),
        ([[0.0, 0.0, 0.0]], [1.0, 2.0], [0.0, 0.1], 5.0, "pose must have shape"),
        ([0.0, 0.0, 0.0], [[1.0, 2.0]], [0.0, 0.1], 5.0, "ranges must be 1-D"),
        ([0.0, 0.0, 0.0], [1.0, 2.0], [0.0, 0.1, 0.2], 5.0, "angles shape"),
        ([0.0, 0.0, 0.0], [1.0, 2.0], [[0.0, 0.1]] * 2, 5.0, "angles shape"),
        ([0.0, 0.0, 0.0], [1.0, 2.0], 0.0, 5.0, ""),
        ([0.0, 0.0, 0.0], [1.0, 2.0], [0.0, np.nan], 5.0, "angles must be finite"),
        ([0.0, 0.0, 0.0], [1.0, 2.0], [-np.inf, 0.0], 5.0, "angles must be finite"),
        ([0.0, 0.0, 0.0], [1.0, 2.0], ["a", "b"], 5.0, "could not convert"),
        ([0.0, 0.0, 0.0], [1.0, 2.0], [0.0, 0.1], 0.0, "max_range must be > 0"),
        ([0.0, 0.0, 0.0], [1.0, 2.0], [0.0, 0.1], -1.0, "max_range must be > 0"),
        ([0.0, 0.0, 0.0], [1.0, 2.0], [0.0, 0.1], np.nan, "max_range must be > 0"),
        ([0.0, 0.0, 0.0], [1.0, 2.0], [0.0, 0.1], "far", "could not convert"),
        ([0.0, 0.0, 0.0], [1e308, 2.0], [0.0, 0.1], np.inf, "max_extent"),
        ([1e308, 0.0, 0.0], [1.7e308, 2.0], [0.0, 0.1], np.inf, "poses must be finite numbers"),
        ([1e306, 0.0, 0.0], [1.0, 2.0], [0.0, 0.1], 5.0, ""),  # numpy: grid too large
    ],
)
def test_single_scan_bad_input_raises_as_the_batch_path(pose, ranges, angles, max_range, error):
    grid = OccupancyGrid(0.1, spec=GridSpec(0.1, (-5.0, -5.0), (100, 100)))
    grid.integrate_scan([0.0, 0.0, 0.0], [1.0, 1.5], [0.3, 0.4], max_range=5.0)
    before = _state(grid)
    with pytest.raises((ValueError, TypeError, IndexError, OverflowError)) as single:
        grid.integrate_scan(pose, ranges, angles, max_range=max_range)
    _assert_same_state(_state(grid), before)  # nothing changed
    assert error in str(single.value)
    if error.startswith(("pose must", "ranges must")):
        return  # integrate_scan's own checks, before either path
    p = np.asarray(pose, dtype=np.float64)[None, :]
    r = np.asarray(ranges, dtype=np.float64)[None, :]
    with pytest.raises(type(single.value)) as batch:
        grid.integrate_scans(p, r, angles, max_range=max_range)
    assert str(batch.value) == str(single.value)


def test_single_scan_that_leaves_the_grid(monkeypatch):
    rng = np.random.default_rng(3)
    poses, ranges, angles = random_scans(rng, 40, 25, spread=2.0)
    poses[:, :2] += np.linspace(0.0, 12.0, 40)[:, None]  # the robot drives away: the grid grows
    model = InverseSensorModel(thickness=0.1, max_clear_range=1.0)
    batch = OccupancyGrid(0.1, model=model)
    single = OccupancyGrid(0.1, model=model)
    spy = _CountGeneral(monkeypatch)
    grown = 0
    for p, r in zip(poses, ranges, strict=True):
        batch.integrate_scans(p[None, :], r[None, :], angles, max_range=3.0)
        calls = spy.calls
        shape = single.spec.shape
        single.integrate_scan(p, r, angles, max_range=3.0)
        assert (spy.calls > calls) == (single.spec.shape != shape)  # general path only to grow
        grown += spy.calls > calls
        _assert_same_state(_state(single), _state(batch))
    assert 1 < grown < 20
    # a fixed grid raises the usual error and keeps its cells
    fixed = OccupancyGrid(0.1, spec=GridSpec(0.1, (-1.0, -1.0), (20, 20)), fixed=True)
    fixed.integrate_scan([0.0, 0.0, 0.0], [0.5], [0.0], max_range=5.0)
    before = _state(fixed)
    with pytest.raises(GridBoundsError, match="outside the fixed grid") as single_err:
        fixed.integrate_scan([0.0, 0.0, 0.0], [0.5, 1.2], [0.0, 0.1], max_range=5.0)
    _assert_same_state(_state(fixed), before)
    with pytest.raises(GridBoundsError) as batch_err:
        fixed.integrate_scans([[0.0, 0.0, 0.0]], [[0.5, 1.2]], [0.0, 0.1], max_range=5.0)
    assert str(batch_err.value) == str(single_err.value)
    # a scan that reaches exactly the last cell stays on the fast path
    calls = spy.calls
    fixed.integrate_scan([0.0, 0.0, 0.0], [0.99], [0.0], max_range=5.0)
    assert spy.calls == calls


def test_single_scan_kernel_codes_leave_the_grid_untouched():
    from probmap.grid import _kernels as k

    grid = OccupancyGrid(0.1, spec=GridSpec(0.1, (-2.0, -2.0), (40, 40)))
    params = grid._fast_params()
    ok = (np.zeros(3), np.array([1.0, 1.5]), np.array([0.0, 1.0]), 5.0)
    cases = [
        (k.SCAN_OK, ok),
        (k.SCAN_BAD_POSE, (np.array([0.0, np.nan, 0.0]), *ok[1:])),
        (k.SCAN_BAD_ANGLES_SHAPE, (ok[0], ok[1], np.zeros(3), 5.0)),
        (k.SCAN_BAD_ANGLES, (ok[0], ok[1], np.array([0.0, np.inf]), 5.0)),
        (k.SCAN_BAD_MAX_RANGE, (*ok[:3], 0.0)),
        (k.SCAN_BAD_MAX_RANGE, (*ok[:3], np.nan)),
        (k.SCAN_OUTSIDE, (ok[0], np.array([1.0, 2.5]), np.array([0.0, np.pi]), 5.0)),
        (k.SCAN_OUTSIDE, (ok[0], np.array([1.0, 1e308]), ok[2], np.inf)),
    ]
    for code, (pose, ranges, angles, max_range) in cases:
        lo, stamp = grid.log_odds.copy(), grid._stamp.copy()
        out = k.integrate_one_scan(lo, stamp, 2, pose, ranges, angles, max_range, params)
        assert out[0] == code
        if code == k.SCAN_OK:
            assert out[1:] == (2, 0, 0, int((stamp == 2).sum()))
        else:
            assert out[1:] == (0, 0, 0, 0)
            np.testing.assert_array_equal(lo, grid.log_odds)
            assert not stamp.any()


def test_growth_past_max_extent_is_refused_and_changes_nothing():
    from probmap.errors import GridBoundsError

    angles = np.array([-0.1, 0.0, 0.1])
    grid = OccupancyGrid(0.1, max_extent=50.0)
    grid.integrate_scan([0.0, 0.0, 0.0], [5.0, 5.0, 5.0], angles, max_range=10.0)
    lo, seen, spec = grid.log_odds.copy(), grid.observed.copy(), grid.spec
    # a pose glitch 1e7 m away, a reading past the limit, a far reading with max_range=inf
    for pose, ranges, max_range in (
        ([1e7, 0.0, 0.0], [5.0, 5.0, 5.0], 10.0),
        ([0.0, 0.0, 0.0], [60.0, 60.0, 60.0], 100.0),
        ([0.0, 0.0, 0.0], [1e9, 1e9, 1e9], math.inf),
    ):
        with pytest.raises(GridBoundsError, match=r"max_extent"):
            grid.integrate_scan(pose, ranges, angles, max_range=max_range)
        assert grid.spec == spec
        np.testing.assert_array_equal(grid.log_odds, lo)
        np.testing.assert_array_equal(grid.observed, seen)
    # within the limit it still grows: 45 m away from the first scan
    grid.integrate_scan([40.0, 0.0, 0.0], [5.0, 5.0, 5.0], angles, max_range=10.0)
    assert grid.spec.extent[1] >= 45.0
    # the default limit is a few km: a 1 km building grows, a 1e9 m reading does not
    big = OccupancyGrid(0.5)
    big.integrate_scan([0.0, 0.0, 0.0], [1000.0] * 3, angles, max_range=2000.0)
    with pytest.raises(GridBoundsError, match="3000 m a side"):
        big.integrate_scan([0.0, 0.0, 0.0], [1e9] * 3, angles)
    with pytest.raises(ValueError, match="max_extent"):
        OccupancyGrid(0.1, max_extent=0.0)


# ------------------------------------------------------------------ lazily resident arrays
@pytest.mark.parametrize("lazy_bytes", [1 << 22, 1])
def test_filled_equals_np_full_bit_for_bit(monkeypatch, lazy_bytes):
    # all-zero fills from lazy_bytes on are anonymous memory maps (pages no scan writes stay
    # unresident); the values, dtype and sign bits are those of np.full, including a negative
    # zero (not all-zero bits), and the arrays are writable
    from probmap.grid import _storage

    monkeypatch.setattr(_storage, "LAZY_BYTES", lazy_bytes)
    for fill in (np.float32(0.0), np.float32(-0.0), np.float32(0.4), np.uint8(0), np.uint8(3)):
        got = _storage.filled((5, 7), fill)
        want = np.full((5, 7), fill, dtype=fill.dtype)
        assert got.dtype == want.dtype and got.shape == want.shape
        assert got.tobytes() == want.tobytes()
        got[2, 3] = want[2, 3] = 1
        assert got.tobytes() == want.tobytes()


def test_grid_on_lazy_zero_pages_integrates_like_np_full(monkeypatch):
    # the same scans into a grid whose arrays are memory maps and into one built on np.full
    from probmap.grid import _storage

    spec = GridSpec(0.1, (-6.0, -6.0), (120, 120))
    angles = np.linspace(-np.pi / 2, np.pi / 2, 91)
    ranges = 2.0 + np.random.default_rng(1).random((300, 91))
    poses = np.column_stack([np.linspace(-1, 1, 300), np.zeros(300), np.linspace(0, 3, 300)])
    grids = []
    for lazy in (1, 1 << 62):
        monkeypatch.setattr(_storage, "LAZY_BYTES", lazy)
        g = OccupancyGrid(0.1, spec=spec)
        for p, r in zip(poses, ranges, strict=True):  # past a stamp epoch (254 scans)
            g.integrate_scan(p, r, angles, max_range=4.0)
        grids.append(g)
    # the first grid's arrays live on a memory map, the second's are numpy's own
    assert not grids[0].log_odds.flags.owndata and grids[1].log_odds.flags.owndata
    np.testing.assert_array_equal(grids[0].log_odds, grids[1].log_odds)
    np.testing.assert_array_equal(grids[0].observed, grids[1].observed)


def test_reset_stamps_equals_np_minimum():
    # a new stamp epoch, written block of rows by block of rows (a ragged last block)
    from probmap.grid._storage import reset_stamps

    stamp = np.random.default_rng(2).integers(0, 256, (11, 13)).astype(np.uint8)
    want = np.minimum(stamp, 1)
    reset_stamps(stamp, rows=4)
    np.testing.assert_array_equal(stamp, want)
    assert stamp.dtype == np.uint8
