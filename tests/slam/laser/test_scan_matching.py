"""Scan matcher: kernels against pure-Python references, derivatives against numerical ones,
recovery of a known offset on the simulated world."""

from __future__ import annotations

import math

import numpy as np
import pytest

from probmap.grid.occupancy import OccupancyGrid
from probmap.grid.spec import GridSpec
from probmap.sim.floorplan import simulate_laser_world
from probmap.slam.laser.scan_matching import (
    MatcherConfig,
    MatchField,
    correlative_distribution,
    correlative_search,
    match_scan,
    normal_equations,
    point_terms,
    refine,
    scan_points,
    score_scan,
)


# ----------------------------------------------------------------- pure-Python references
def ref_bilinear(f: MatchField, x: float, y: float) -> float:
    u = (x - f.origin[0]) / f.resolution - 0.5
    v = (y - f.origin[1]) / f.resolution - 0.5
    i, j = math.floor(u), math.floor(v)
    h, w = f.values.shape
    if i < 0 or j < 0 or i + 1 >= w or j + 1 >= h:
        return 0.0
    a, b = u - i, v - j
    F = f.values
    return float(
        (1 - a) * (1 - b) * F[j, i]
        + a * (1 - b) * F[j, i + 1]
        + (1 - a) * b * F[j + 1, i]
        + a * b * F[j + 1, i + 1]
    )


def ref_world(pose, p):
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return pose[0] + c * p[0] - s * p[1], pose[1] + s * p[0] + c * p[1]


def ref_nearest(f: MatchField, pts, pose) -> float:
    total = 0.0
    h, w = f.values.shape
    for p in pts:
        qx, qy = ref_world(pose, p)
        ix = math.floor((qx - f.origin[0]) / f.resolution)
        iy = math.floor((qy - f.origin[1]) / f.resolution)
        if 0 <= ix < w and 0 <= iy < h:
            total += f.values[iy, ix]
    return total


def ref_search(f, pts, p0, cfg):
    nl = round(cfg.linear_window / cfg.linear_step)
    na = round(cfg.angular_window / cfg.angular_step)
    best, arg = -1.0, None
    for ka in range(-na, na + 1):
        for kx in range(-nl, nl + 1):
            for ky in range(-nl, nl + 1):
                pose = (
                    p0[0] + kx * cfg.linear_step,
                    p0[1] + ky * cfg.linear_step,
                    p0[2] + ka * cfg.angular_step,
                )
                s = ref_nearest(f, pts, pose)
                if s > best:
                    best, arg = s, pose
    return np.array(arg), best


@pytest.fixture(scope="module")
def world():
    return simulate_laser_world(seed=3, range_noise=0.005)


@pytest.fixture(scope="module")
def grid(world):
    # a map as scans see it (wall surfaces only), built with the true poses
    g = OccupancyGrid(resolution=0.05)
    g.integrate_scans(world.poses, world.ranges, world.angles, max_range=world.max_range)
    return g


@pytest.fixture(scope="module")
def field(grid):
    return MatchField.from_grid(grid, sigma=0.08)


def _points(world, k):
    return scan_points(world.ranges[k], world.angles, world.max_range)


def test_field_is_one_on_walls_and_the_gaussian_of_the_distance_elsewhere():
    occ = np.zeros((5, 7), dtype=bool)
    occ[2, 3] = True
    spec = GridSpec(0.1, (-1.0, 2.0), (5, 7))
    f = MatchField.from_occupied(occ, spec, sigma=0.2)
    iy, ix = np.mgrid[0:5, 0:7]
    d = 0.1 * np.hypot(iy - 2, ix - 3)
    np.testing.assert_allclose(f.values, np.exp(-0.5 * (d / 0.2) ** 2))
    assert f.origin == (-1.0, 2.0)
    with pytest.raises(ValueError, match="shape"):
        MatchField.from_occupied(occ[:4], spec)


def test_point_terms_match_reference_and_numerical_derivatives(world, field):
    pts = _points(world, 10)[::7]
    pose = world.poses[10] + np.array([0.013, -0.021, 0.012])
    terms = point_terms(field, pts, pose)
    eps = 1e-6
    for i, p in enumerate(pts):
        assert terms[i, 0] == pytest.approx(ref_bilinear(field, *ref_world(pose, p)), abs=1e-12)
        for a in range(3):
            d = np.zeros(3)
            d[a] = eps
            num = (
                ref_bilinear(field, *ref_world(pose + d, p))
                - ref_bilinear(field, *ref_world(pose - d, p))
            ) / (2 * eps)
            assert terms[i, 1 + a] == pytest.approx(num, rel=1e-4, abs=1e-4)


def test_normal_equations_gradient_is_numerical_derivative_of_cost(world, field):
    pts = _points(world, 20)
    pose = world.poses[20] + np.array([0.02, 0.01, -0.015])

    def cost(q):
        return 0.5 * sum((1 - ref_bilinear(field, *ref_world(q, p))) ** 2 for p in pts)

    score, g, H = normal_equations(field, pts, pose)
    terms = point_terms(field, pts, pose)
    assert score == pytest.approx(terms[:, 0].sum())
    J = -terms[:, 1:]
    np.testing.assert_allclose(H, J.T @ J, rtol=1e-10, atol=1e-10)
    eps = 1e-6
    num = [
        (cost(pose + eps * np.eye(3)[a]) - cost(pose - eps * np.eye(3)[a])) / (2 * eps)
        for a in range(3)
    ]
    np.testing.assert_allclose(g, num, rtol=1e-4, atol=1e-4)


def test_nearest_score_and_correlative_search_match_references(world, field):
    pts = _points(world, 30)[::5]
    p0 = world.poses[30] + np.array([0.1, -0.05, 0.03])
    assert score_scan(field, pts, p0) == pytest.approx(ref_nearest(field, pts, p0), abs=1e-9)
    cfg = MatcherConfig(linear_window=0.15, linear_step=0.05, angular_window=0.04)
    pose, s = correlative_search(field, pts, p0, cfg)
    rpose, rs = ref_search(field, pts, p0, cfg)
    assert s == pytest.approx(rs, abs=1e-9)
    np.testing.assert_allclose(pose, rpose, atol=1e-12)


@pytest.mark.parametrize("temperature", [0.5, 3.0])
def test_correlative_distribution_matches_reference(world, field, temperature):
    pts = _points(world, 30)[::5]
    p0 = world.poses[30] + np.array([0.04, -0.03, 0.02])
    cfg = MatcherConfig(linear_window=0.1, linear_step=0.05, angular_window=0.02)
    mean, cov, arg, best = correlative_distribution(field, pts, p0, cfg, temperature)
    offs, scores = [], []
    for ka in range(-2, 3):
        for kx in range(-2, 3):
            for ky in range(-2, 3):
                d = (kx * 0.05, ky * 0.05, ka * 0.01)
                offs.append(d)
                scores.append(ref_nearest(field, pts, p0 + np.array(d)))
    offs, scores = np.array(offs), np.array(scores)
    w = np.exp((scores - scores.max()) / temperature)
    mu = w @ offs / w.sum()
    e = offs - mu
    assert best == pytest.approx(scores.max(), abs=1e-9)
    np.testing.assert_allclose(arg, correlative_search(field, pts, p0, cfg)[0], atol=1e-12)
    np.testing.assert_allclose(mean, p0 + mu, atol=1e-12)
    np.testing.assert_allclose(cov, (w[:, None] * e).T @ e / w.sum(), atol=1e-12)


def test_correlative_distribution_is_wide_along_a_featureless_corridor():
    # two long parallel walls: the score is flat along x, sharp across
    spec = GridSpec(0.05, (0.0, 0.0), (60, 400))
    occ = np.zeros(spec.shape, bool)
    occ[10, :] = occ[50, :] = True
    fld = MatchField.from_occupied(occ, spec, 0.05)
    xs = np.linspace(-4, 4, 120)
    pts = np.concatenate(
        [np.column_stack([xs, np.full(120, -0.975)]), np.column_stack([xs, np.full(120, 1.025)])]
    )
    cfg = MatcherConfig(linear_window=0.1, linear_step=0.025, angular_window=0.0)
    mean, cov, arg, _ = correlative_distribution(fld, pts, (10.0, 1.5, 0.0), cfg)
    assert abs(mean[0] - 10.0) < 1e-9  # flat along x: the mean stays put
    assert abs(mean[1] - 1.5) < 0.0125  # sharp across: the walls' position
    assert np.sqrt(cov[0, 0]) > 0.06 and np.sqrt(cov[1, 1]) < 0.025  # ties within one cell
    # the best pose of the plain search is the first of the ties, 0.1 m off
    assert arg[0] == pytest.approx(9.9)


def ref_refine(f, pts, p0, iterations, max_step):
    """Gauss-Newton on sum (1 - M)^2 in plain numpy: damped normal equations, shortened
    steps, a step kept only if it lowers the cost."""

    def terms(p):
        t = point_terms(f, pts, p)
        r = 1.0 - t[:, 0]
        J = -t[:, 1:]
        return J.T @ r, J.T @ J, float(r @ r)

    p = np.asarray(p0, dtype=float)
    g, H, sq = terms(p)
    taken = 0
    for it in range(1, iterations + 1):
        step = -np.linalg.solve(H + 1e-9 * np.eye(3) + 1e-6 * np.diag(np.diag(H)), g)
        shrink = max(math.hypot(step[0], step[1]) / max_step[0], abs(step[2]) / max_step[1])
        if shrink > 1:
            step = step / shrink
        g2, H2, sq2 = terms(p + step)
        if not sq2 < sq:
            break
        taken, p, g, H, sq = it, p + step, g2, H2, sq2
        if abs(step[0]) + abs(step[1]) < 1e-5 and abs(step[2]) < 1e-5:
            break
    return p, H, taken


def test_solve3_matches_numpy():
    from probmap.slam.laser import _match_kernels as K

    rng = np.random.default_rng(5)
    for _ in range(20):
        A = rng.normal(size=(3, 3))
        b = rng.normal(size=3)
        x = np.empty(3)
        assert K.solve3(A, b, x)
        np.testing.assert_allclose(x, np.linalg.solve(A, b), rtol=1e-9, atol=1e-12)
    assert not K.solve3(np.zeros((3, 3)), b, x)


@pytest.mark.parametrize("k", [15, 60])
def test_refine_kernel_matches_reference(world, field, k):
    pts = _points(world, k)
    p0 = world.poses[k] + np.array([0.03, -0.02, 0.01])
    pose, cov, it = refine(field, pts, p0, 8, (0.025, 0.0125))
    rpose, rH, rit = ref_refine(field, pts, p0, 8, (0.025, 0.0125))
    assert it == rit and it >= 1
    np.testing.assert_allclose(pose[:2], rpose[:2], atol=1e-9)
    assert pose[2] == pytest.approx(math.remainder(rpose[2], 2 * math.pi), abs=1e-9)
    # covariance = residual variance x (J^T J)^-1 at the final pose
    _, _, H = normal_equations(field, pts, pose)
    np.testing.assert_allclose(H, rH, rtol=1e-9, atol=1e-9)
    r = 1.0 - point_terms(field, pts, pose)[:, 0]
    var_r = max(float(r @ r) / (len(pts) - 3), 1e-6)
    np.testing.assert_allclose(cov @ (H + 1e-9 * np.eye(3)), var_r * np.eye(3), atol=1e-9)


@pytest.mark.parametrize("k", [15, 60, 120])
def test_match_recovers_a_known_offset(world, field, k):
    pts = _points(world, k)
    truth = world.poses[k]
    res = match_scan(field, pts, truth + np.array([0.12, -0.09, 0.06]))
    assert np.hypot(*(res.pose[:2] - truth[:2])) < 0.02
    assert abs(res.pose[2] - truth[2]) < 0.01
    assert res.score > 0.5
    # a positive-definite covariance, small where the geometry constrains the pose
    assert np.all(np.linalg.eigvalsh(res.covariance) > 0)
    assert np.sqrt(res.covariance[0, 0]) < 0.05


def test_bad_input_is_refused(field):
    with pytest.raises(ValueError, match="points"):
        match_scan(field, np.zeros((4, 3)), [0, 0, 0])
    with pytest.raises(ValueError, match="at least 3"):
        match_scan(field, np.zeros((2, 2)), [0, 0, 0])
    with pytest.raises(ValueError, match="pose"):
        match_scan(field, np.zeros((5, 2)), [0, np.nan, 0])
    with pytest.raises(ValueError, match="sigma"):
        MatcherConfig(sigma=0)
    with pytest.raises(ValueError, match="angles"):
        scan_points([1.0, 2.0], [0.0], 10.0)
