"""Loop-closure search: max-grids against block maxima, branch and bound against brute force
and both against a pure-Python scoring of the window, a known displacement in a simulated room,
and input validation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from probmap.grid.spec import GridSpec
from probmap.slam.laser import _bnb_kernels as K
from probmap.slam.laser.loop_closure import (
    LoopClosureMatch,
    PrecomputedGrids,
    SearchResult,
    branch_and_bound_search,
    brute_force_search,
    default_angular_step,
    match_loop_closure,
)
from probmap.slam.laser.scan_matching import MatchField, score_scan

TABLE = np.arange(256) / 255.0


# ----------------------------------------------------------------- pure-Python references
def ref_codes(v):
    """The smallest code whose value is at least v."""
    return np.searchsorted(TABLE, v, side="left")


def ref_max_grid(values, h):
    """Max over the 2^h x 2^h block starting at each cell (ix, iy) >= -(2^h - 1), 0 outside."""
    H, W = values.shape
    b = 2**h
    p = b - 1
    z = np.zeros((H + 2 * p, W + 2 * p))
    z[p : p + H, p : p + W] = values
    out = np.empty((H + p, W + p))
    for j in range(H + p):
        for i in range(W + p):
            out[j, i] = np.max(z[j : j + b, i : i + b])
    return out


def ref_cells(values, origin, res, pts, center, theta):
    """Cells of the points seen from the window centre at heading theta (python floats)."""
    c, s = math.cos(theta), math.sin(theta)
    cells = []
    for px, py in pts:
        qx = center[0] + (c * px - s * py)
        qy = center[1] + (s * px + c * py)
        cells.append((math.floor((qx - origin[0]) / res), math.floor((qy - origin[1]) / res)))
    return cells


def ref_window(values, origin, res, pts, center, lin, ang, step, min_score):
    """Every candidate's score, in the order (ka, kx, ky); the best with the first-of-equals
    rule; None when nothing reaches min_score."""
    H, W = values.shape
    nl = math.floor(lin / res + 1e-9)
    na = math.floor(ang / step + 1e-9)
    best, arg = -1.0, None
    for ka in range(-na, na + 1):
        cells = ref_cells(values, origin, res, pts, center, center[2] + ka * step)
        for kx in range(-nl, nl + 1):
            for ky in range(-nl, nl + 1):
                total = 0.0
                for ix, iy in cells:
                    if 0 <= ix + kx < W and 0 <= iy + ky < H:
                        total += values[iy + ky, ix + kx]
                m = total / len(pts)
                if m >= min_score and m > best:
                    best, arg = m, (ka, kx, ky)
    if arg is None:
        return None
    ka, kx, ky = arg
    return best, (center[0] + kx * res, center[1] + ky * res, center[2] + ka * step)


def wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


# ----------------------------------------------------------------- random problems
def random_values(rng, kind, shape):
    if kind == "uniform":
        return rng.random(shape)
    if kind == "binary":  # plateaus: many equal scores, the tie rule matters
        return (rng.random(shape) < 0.15).astype(float)
    if kind == "levels":  # few distinct values, some of them exact codes
        return rng.choice([0.0, 0.2, 0.5, 1.0, 77 / 255], size=shape)
    occ = rng.random(shape) < 0.03
    spec = GridSpec(0.1, (0.0, 0.0), shape)
    return MatchField.from_occupied(occ, spec, sigma=0.12).values


def random_problem(seed):
    rng = np.random.default_rng(seed)
    kind = ["uniform", "binary", "levels", "field"][seed % 4]
    H, W = (int(v) for v in rng.integers(1, 70, size=2))
    res = float(rng.choice([0.05, 0.1, 0.25]))
    origin = (float(rng.uniform(-3, 3)), float(rng.uniform(-3, 3)))
    values = random_values(rng, kind, (H, W))
    depth = int(rng.integers(1, 8))
    n = int(rng.integers(1, 40))
    pts = rng.normal(scale=rng.uniform(0.2, 2.5), size=(n, 2))
    centre = np.array(
        [
            origin[0] + rng.uniform(-0.2, 1.2) * W * res,
            origin[1] + rng.uniform(-0.2, 1.2) * H * res,
            rng.uniform(-math.pi, math.pi),
        ]
    )
    lin = float(rng.uniform(0, 1.5) * max(H, W) * res / 2)
    ang = float(rng.uniform(0, 0.4))
    step = None if rng.random() < 0.3 else float(rng.uniform(0.02, 0.15))
    min_score = float(rng.choice([0.0, 0.0, rng.uniform(0.0, 0.8)]))
    return values, origin, res, depth, pts, centre, lin, ang, step, min_score


# ----------------------------------------------------------------- max-grids
@pytest.mark.parametrize(
    "shape,depth", [((1, 1), 3), ((3, 17), 4), ((37, 23), 6), ((16, 16), 5), ((9, 40), 1)]
)
def test_max_grids_equal_block_maxima_rounded_up_to_a_code(shape, depth):
    rng = np.random.default_rng(shape[0] * 100 + shape[1])
    v = rng.random(shape)
    v[rng.random(shape) < 0.2] = 0.0
    v[rng.random(shape) < 0.05] = 1.0
    v[rng.random(shape) < 0.05] = 13 / 255  # exact codes
    g = PrecomputedGrids(v, (0.5, -1.0), 0.1, depth=depth)
    assert g.max_grid(0) is not g.values
    np.testing.assert_array_equal(g.max_grid(0), v)
    for h in range(1, depth):
        m = ref_max_grid(v, h)
        got = g.max_grid(h)
        assert got.shape == (shape[0] + 2**h - 1, shape[1] + 2**h - 1)
        np.testing.assert_array_equal(got, TABLE[ref_codes(m)])
        assert (got >= m).all() and (got <= m + 1 / 255 + 1e-15).all()
    with pytest.raises(ValueError, match="h must be"):
        g.max_grid(depth)


def test_quantize_up_gives_the_smallest_code_not_below_the_value():
    rng = np.random.default_rng(5)
    v = np.concatenate([rng.random(2000), TABLE, np.nextafter(TABLE[1:], 0), [0.0, 1.0]])
    v = v.reshape(1, -1)
    out = np.empty(v.shape, dtype=np.uint8)
    K.quantize_up(v, TABLE, out)
    np.testing.assert_array_equal(out, ref_codes(v))


def test_precomputed_grids_share_the_field_and_are_read_only():
    rng = np.random.default_rng(0)
    f = MatchField(rng.random((30, 20)), (1.0, 2.0), 0.05)
    g = PrecomputedGrids.from_field(f, depth=4)
    assert g.values is f.values and g.origin == (1.0, 2.0) and g.resolution == 0.05
    assert g.shape == (30, 20) and g.depth == 4
    assert g.nbytes == sum((30 + 2**h - 1) * (20 + 2**h - 1) for h in range(1, 4))
    with pytest.raises(AttributeError):
        g.depth = 3  # type: ignore[misc]
    copy = PrecomputedGrids(f.values.tolist(), f.origin, f.resolution)
    assert not copy.values.flags.writeable


def test_cell_tables_match_reference():
    rng = np.random.default_rng(1)
    pts = rng.normal(scale=3.0, size=(25, 2))
    cx = np.empty((7, 25), dtype=np.int64)
    cy = np.empty_like(cx)
    K.cell_tables(pts, 1.3, -0.4, 0.7, 0.05, 7, -2.0, -3.0, 0.05, cx, cy)
    for a in range(7):
        cells = ref_cells(None, (-2.0, -3.0), 0.05, pts, (1.3, -0.4), 0.7 + (a - 3) * 0.05)
        np.testing.assert_array_equal(np.column_stack([cx[a], cy[a]]), cells)


def test_node_bound_is_the_max_grid_sum_and_bounds_every_candidate_of_the_node():
    rng = np.random.default_rng(2)
    v = random_values(rng, "field", (40, 50))
    g = PrecomputedGrids(v, (0.0, 0.0), 0.1, depth=5)
    pts = rng.uniform(-2, 2, size=(30, 2))
    cx = np.empty((1, 30), dtype=np.int64)
    cy = np.empty_like(cx)
    K.cell_tables(pts, 2.5, 2.0, 0.3, 0.1, 1, 0.0, 0.0, 0.1, cx, cy)
    for h in range(1, 5):
        m = g.max_grid(h)
        p = 2**h - 1
        for _ in range(20):
            kx, ky = (int(k) for k in rng.integers(-30, 30, size=2))
            bound = K.node_sum(g._buf, g._levels, h, TABLE, cx[0], cy[0], kx, ky)
            ref = 0.0
            for ix, iy in zip(cx[0] + kx, cy[0] + ky, strict=True):
                if 0 <= iy + p < m.shape[0] and 0 <= ix + p < m.shape[1]:
                    ref += m[iy + p, ix + p]
            assert bound == pytest.approx(ref, abs=1e-12)
            leaves = [
                K.leaf_sum(v, cx[0], cy[0], kx + dx, ky + dy)
                for dx in range(2**h)
                for dy in range(2**h)
            ]
            assert bound >= max(leaves)


@pytest.mark.parametrize("seed", range(16))
def test_root_bounds_keep_exactly_the_roots_that_reach_min_score(seed):
    # the oracle: every root scored on its own, as a pure-Python sum over the max-grid
    rng = np.random.default_rng(40 + seed)
    v = random_values(rng, ["field", "uniform", "binary", "levels"][seed % 4], (60, 45))
    top = int(rng.integers(2, 5))
    g = PrecomputedGrids(v, (0.0, 0.0), 0.1, depth=top + 1)
    pts = rng.uniform(-2.5, 2.5, size=(int(rng.integers(5, 30)), 2))
    # even seeds: the default step (the farthest point moves up to a cell per heading), so a
    # group's cells span up to a block; odd seeds: a step too coarse to group the headings
    step = 0.1 / float(np.hypot(pts[:, 0], pts[:, 1]).max()) if seed % 2 == 0 else 0.2
    n_angles = int(rng.integers(1, 3 * 2**top))
    cx = np.empty((n_angles, len(pts)), dtype=np.int64)
    cy = np.empty_like(cx)
    K.cell_tables(pts, 2.2, 3.0, 0.4, step, n_angles, 0.0, 0.0, 0.1, cx, cy)
    nl = int(rng.integers(2**top, 4 * 2**top))
    side = 2**top
    per_axis = (2 * nl) // side + 1
    m = g.max_grid(top)
    pad = side - 1
    exact = np.empty(n_angles * per_axis * per_axis)
    for a in range(n_angles):
        for i in range(per_axis):
            for j in range(per_axis):
                total = 0.0
                for ix, iy in zip(cx[a] - nl + i * side, cy[a] - nl + j * side, strict=True):
                    if 0 <= iy + pad < m.shape[0] and 0 <= ix + pad < m.shape[1]:
                        total += m[iy + pad, ix + pad]
                exact[(a * per_axis + i) * per_axis + j] = total / len(pts)
    min_score = float(np.quantile(exact, [0.9, 0.99][seed % 4 // 2]))
    out = np.empty_like(exact)
    count = K.root_bounds(g._buf, g._levels, TABLE, cx, cy, nl, top, min_score, out)
    keep = exact >= min_score
    np.testing.assert_array_equal(out >= min_score, keep)
    np.testing.assert_allclose(out[keep], exact[keep], rtol=0, atol=1e-12)
    assert (out[~keep] < min_score).all()
    if seed % 2 == 0 and n_angles > side:  # grouped: fewer scorings than one per root
        assert count < len(exact)


@pytest.mark.parametrize("seed", range(24))
def test_branch_and_bound_with_a_wide_window_and_fine_headings_matches_brute_force(seed):
    # wide windows (roots of depth >= 2), many headings and a threshold: the grouped roots
    rng = np.random.default_rng(300 + seed)
    v = random_values(rng, ["field", "uniform", "binary", "levels"][seed % 4], (70, 60))
    g = PrecomputedGrids(v, (0.0, 0.0), 0.1, depth=int(rng.integers(3, 7)))
    pts = rng.uniform(-3.0, 3.0, size=(int(rng.integers(5, 40)), 2))
    centre = np.array([rng.uniform(2.0, 4.0), rng.uniform(2.5, 4.5), rng.uniform(-3, 3)])
    lin, ang = float(rng.uniform(0.8, 2.5)), float(rng.uniform(0.05, 0.4))
    bf0 = brute_force_search(g, pts, centre, lin, ang)
    assert bf0 is not None
    min_score = float(rng.choice([0.5, 0.9, 1.0, 1.01])) * bf0.score
    bnb = branch_and_bound_search(g, pts, centre, lin, ang, min_score=min_score)
    bf = brute_force_search(g, pts, centre, lin, ang, min_score=min_score)
    if bf is None:
        assert bnb is None
        return
    assert bnb is not None
    assert bnb.score == bf.score
    np.testing.assert_array_equal(bnb.pose, bf.pose)


# ----------------------------------------------------------------- the search
@pytest.mark.parametrize("seed", range(12))
def test_brute_force_matches_pure_python_scoring_of_the_window(seed):
    values, origin, res, depth, pts, centre, lin, ang, step, min_score = random_problem(seed)
    lin = min(lin, 8 * res)  # keep the pure-Python reference small
    g = PrecomputedGrids(values, origin, res, depth)
    got = brute_force_search(g, pts, centre, lin, ang, step, min_score)
    used = step if step is not None else default_angular_step(pts, res)
    ref = ref_window(values, origin, res, pts, centre, lin, ang, used, min_score)
    if ref is None:
        assert got is None
        return
    assert got is not None
    assert got.score == pytest.approx(ref[0], abs=1e-12)
    assert got.angular_step == used
    assert got.evaluated == got.candidates
    np.testing.assert_allclose(got.pose[:2], ref[1][:2], atol=1e-12)
    assert got.pose[2] == pytest.approx(wrap(ref[1][2]), abs=1e-12)


@pytest.mark.parametrize("seed", range(160))
def test_branch_and_bound_returns_the_brute_force_pose_and_score(seed):
    values, origin, res, depth, pts, centre, lin, ang, step, min_score = random_problem(seed)
    g = PrecomputedGrids(values, origin, res, depth)
    bnb = branch_and_bound_search(g, pts, centre, lin, ang, step, min_score)
    bf = brute_force_search(g, pts, centre, lin, ang, step, min_score)
    if bf is None:
        assert bnb is None
        return
    assert bnb is not None
    assert bnb.score == bf.score  # the same kernel scores both: bit for bit
    np.testing.assert_array_equal(bnb.pose, bf.pose)  # ties broken by the same rule
    assert bnb.candidates == bf.candidates and bnb.angular_step == bf.angular_step


def test_branch_and_bound_on_a_plateau_returns_the_first_of_equals():
    # every candidate scores 1: the smallest (ka, kx, ky) wins, as brute force's order says
    g = PrecomputedGrids(np.ones((50, 50)), (0.0, 0.0), 0.1, depth=4)
    pts = np.array([[0.05, 0.0], [0.0, 0.05]])
    r = branch_and_bound_search(g, pts, (2.5, 2.5, 0.0), 0.5, 0.2, 0.1)
    assert r is not None and r.score == 1.0
    np.testing.assert_allclose(r.pose, [2.0, 2.0, -0.2])
    assert r.evaluated < r.candidates


def test_score_is_the_nearest_cell_score_of_the_returned_pose():
    rng = np.random.default_rng(3)
    f = MatchField(random_values(rng, "field", (60, 60)), (-1.0, -1.0), 0.1)
    g = PrecomputedGrids.from_field(f)
    pts = rng.uniform(-2.0, 2.0, size=(50, 2))
    r = branch_and_bound_search(g, pts, (2.0, 2.0, 0.1), 1.0, 0.3)
    assert r is not None
    assert r.score == pytest.approx(score_scan(f, pts, r.pose) / 50, abs=1e-12)


def test_min_score_returns_none_when_nothing_reaches_it():
    rng = np.random.default_rng(4)
    g = PrecomputedGrids(random_values(rng, "uniform", (30, 30)), (0.0, 0.0), 0.1)
    pts = rng.uniform(-1, 1, size=(20, 2))
    best = brute_force_search(g, pts, (1.5, 1.5, 0.0), 0.5, 0.1)
    assert best is not None
    at = branch_and_bound_search(g, pts, (1.5, 1.5, 0.0), 0.5, 0.1, min_score=best.score)
    assert at is not None and at.score == best.score
    above = math.nextafter(best.score, 2.0)
    assert branch_and_bound_search(g, pts, (1.5, 1.5, 0.0), 0.5, 0.1, min_score=above) is None
    assert brute_force_search(g, pts, (1.5, 1.5, 0.0), 0.5, 0.1, min_score=above) is None
    far = branch_and_bound_search(g, pts, (100.0, 0.0, 0.0), 0.5, 0.1, min_score=1e-9)
    assert far is None  # every point outside the grid scores 0


def test_window_of_one_candidate_and_default_step():
    g = PrecomputedGrids(np.full((10, 10), 0.5), (0.0, 0.0), 0.1)
    pts = np.array([[0.3, 0.4], [0.0, 0.1]])
    r = branch_and_bound_search(g, pts, (0.5, 0.5, 0.2), 0.0, 0.0)
    assert r is not None and r.candidates == 1 and r.score == 0.5
    np.testing.assert_allclose(r.pose, [0.5, 0.5, 0.2])
    d = default_angular_step(pts, 0.1)
    assert d == pytest.approx(math.acos(1 - 0.01 / (2 * 0.25)))
    assert 2 * 0.5 * math.sin(d / 2) == pytest.approx(0.1)  # the farthest point moves one cell
    with pytest.raises(ValueError, match="sensor origin"):
        default_angular_step(np.zeros((3, 2)), 0.1)
    r0 = branch_and_bound_search(g, np.zeros((3, 2)), (0.5, 0.5, 0.0), 0.2, 0.0)
    assert r0 is not None and r0.candidates == 25


# ----------------------------------------------------------------- a simulated room
def room_segments():
    """An 8 x 6 m room with a pillar, a notch and a cabinet (x0, y0, x1, y1) in metres."""
    segs = [(0, 0, 8, 0), (8, 0, 8, 6), (8, 6, 0, 6), (0, 6, 0, 0)]
    segs += [(2.0, 2.0, 2.4, 2.0), (2.4, 2.0, 2.4, 2.4), (2.4, 2.4, 2.0, 2.4), (2.0, 2.4, 2.0, 2.0)]
    segs += [(5.0, 6.0, 5.0, 4.8), (5.0, 4.8, 6.5, 4.8), (6.5, 4.8, 6.5, 6.0)]
    segs += [(8.0, 1.0, 7.2, 1.0), (7.2, 1.0, 7.2, 2.5), (7.2, 2.5, 8.0, 2.5)]
    return np.array(segs, dtype=float)


def cast(segs, pose, angles, max_range=10.0):
    """Ranges of beams from pose against segments (nearest intersection)."""
    out = np.full(len(angles), max_range)
    o = np.array(pose[:2])
    for b, a in enumerate(angles):
        d = np.array([math.cos(pose[2] + a), math.sin(pose[2] + a)])
        for x0, y0, x1, y1 in segs:
            e = np.array([x1 - x0, y1 - y0])
            den = d[0] * (-e[1]) + d[1] * e[0]
            if abs(den) < 1e-12:
                continue
            w = np.array([x0, y0]) - o
            t = (w[0] * (-e[1]) + w[1] * e[0]) / den
            u = (d[0] * w[1] - d[1] * w[0]) / den
            if t > 0 and 0 <= u <= 1:
                out[b] = min(out[b], t)
    return out


@pytest.fixture(scope="module")
def room():
    # every wall on a row or column of cell centres: the field peaks on the wall itself
    spec = GridSpec(0.05, (-1.025, -1.025), (160, 200))
    occ = np.zeros(spec.shape, dtype=bool)
    for x0, y0, x1, y1 in room_segments():
        s = np.linspace(0, 1, int(math.hypot(x1 - x0, y1 - y0) / 0.01) + 2)
        cells = spec.world_to_cell(np.column_stack([x0 + s * (x1 - x0), y0 + s * (y1 - y0)]))
        occ[cells[:, 1], cells[:, 0]] = True
    return MatchField.from_occupied(occ, spec, sigma=0.05)


@pytest.mark.parametrize(
    "truth,error",
    [((3.1, 3.3, 0.4), (0.8, -0.6, 0.15)), ((5.7, 2.2, -2.0), (-1.1, 0.9, -0.25))],
)
def test_finds_a_known_displacement_in_a_simulated_room(room, truth, error):
    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    rng = np.random.default_rng(7)
    r = cast(room_segments(), truth, angles) + rng.normal(0, 0.005, 360)
    pts = np.column_stack([r * np.cos(angles), r * np.sin(angles)])[::2]
    g = PrecomputedGrids.from_field(room)
    centre = np.add(truth, error)
    found = branch_and_bound_search(g, pts, centre, 1.5, 0.35, min_score=0.5)
    assert found is not None
    bf = brute_force_search(g, pts, centre, 1.5, 0.35, min_score=0.5)
    assert bf is not None and bf.score == found.score
    np.testing.assert_array_equal(found.pose, bf.pose)
    assert found.evaluated < found.candidates / 20
    assert np.abs(found.pose[:2] - truth[:2]).max() <= 0.05 + 1e-9  # one cell
    assert abs(wrap(found.pose[2] - truth[2])) <= found.angular_step
    m = match_loop_closure(g, room, pts, centre, 1.5, 0.35, min_score=0.5)
    assert isinstance(m, LoopClosureMatch) and isinstance(m.search, SearchResult)
    assert m.search_score == found.score and m.score > 0.8
    assert np.hypot(*(m.pose[:2] - truth[:2])) < 0.015
    assert abs(wrap(m.pose[2] - truth[2])) < 0.003
    assert m.covariance.shape == (3, 3) and np.all(np.linalg.eigvalsh(m.covariance) > 0)
    assert match_loop_closure(g, room, pts, centre, 1.5, 0.35, min_score=1.01) is None


# ----------------------------------------------------------------- validation
def test_bad_inputs_raise():
    g = PrecomputedGrids(np.zeros((5, 5)), (0.0, 0.0), 0.1)
    pts = np.ones((4, 2))
    for fn in (branch_and_bound_search, brute_force_search):
        with pytest.raises(ValueError, match="points"):
            fn(g, np.ones((4, 3)), (0, 0, 0), 1.0, 0.1)
        with pytest.raises(ValueError, match="points"):
            fn(g, np.ones((0, 2)), (0, 0, 0), 1.0, 0.1)
        with pytest.raises(ValueError, match="finite"):
            fn(g, np.array([[np.nan, 1.0]]), (0, 0, 0), 1.0, 0.1)
        with pytest.raises(ValueError, match="center"):
            fn(g, pts, (0, 0), 1.0, 0.1)
        with pytest.raises(ValueError, match="center"):
            fn(g, pts, (0, np.inf, 0), 1.0, 0.1)
        with pytest.raises(ValueError, match="linear_window"):
            fn(g, pts, (0, 0, 0), -1.0, 0.1)
        with pytest.raises(ValueError, match="angular_window"):
            fn(g, pts, (0, 0, 0), 1.0, -0.1)
        with pytest.raises(ValueError, match="angular_window"):
            fn(g, pts, (0, 0, 0), 1.0, 30.0)  # degrees by mistake
        with pytest.raises(ValueError, match="angular_step"):
            fn(g, pts, (0, 0, 0), 1.0, 0.1, 0.0)
        with pytest.raises(ValueError, match="min_score"):
            fn(g, pts, (0, 0, 0), 1.0, 0.1, None, math.nan)
        with pytest.raises(ValueError, match="headings"):
            fn(g, np.ones((1000, 2)), (0, 0, 0), 1.0, 3.0, 1e-5)
        with pytest.raises(TypeError, match="PrecomputedGrids"):
            fn(np.zeros((5, 5)), pts, (0, 0, 0), 1.0, 0.1)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="2-D"):
        PrecomputedGrids(np.zeros(5), (0.0, 0.0), 0.1)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        PrecomputedGrids(np.full((3, 3), 1.5), (0.0, 0.0), 0.1)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        PrecomputedGrids(np.full((3, 3), np.nan), (0.0, 0.0), 0.1)
    with pytest.raises(ValueError, match="resolution"):
        PrecomputedGrids(np.zeros((3, 3)), (0.0, 0.0), 0.0)
    with pytest.raises(ValueError, match="origin"):
        PrecomputedGrids(np.zeros((3, 3)), (0.0, math.nan), 0.1)
    with pytest.raises(ValueError, match="depth"):
        PrecomputedGrids(np.zeros((3, 3)), (0.0, 0.0), 0.1, depth=0)
    with pytest.raises(TypeError, match="depth"):
        PrecomputedGrids(np.zeros((3, 3)), (0.0, 0.0), 0.1, depth=2.5)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="MatchField"):
        PrecomputedGrids.from_field(np.zeros((3, 3)))  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="MatchField"):
        match_loop_closure(g, np.zeros((5, 5)), pts, (0, 0, 0), 1.0, 0.1)  # type: ignore[arg-type]
