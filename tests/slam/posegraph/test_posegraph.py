"""SE(2) pose-graph optimizer: residuals and LM against GTSAM, the closed form of a linear
problem, analytic Jacobians against numerical ones, every numba kernel against a numpy
reference, robust kernels against a false loop closure, LAGO, and the class tier against the
function tier."""

from __future__ import annotations

import math

import numpy as np
import pytest

from probmap.datasets.g2o import write_pose_graph_g2o
from probmap.geometry.se2 import between, compose, inverse, wrap_angle
from probmap.slam.posegraph import _kernels as K
from probmap.slam.posegraph.optimize import (
    OptimizerConfig,
    PoseGraph2D,
    _NormalEquations,
    edge_residuals,
    graph_error,
    lago_initialization,
    optimize_pose_graph,
)

# --------------------------------------------------------------------------- references


def ref_logmap(d: np.ndarray) -> np.ndarray:
    """Pose2 logarithm (Lynch & Park, Modern Robotics 3.3.3.2), straight from the formula."""
    x, y, th = d[..., 0], d[..., 1], wrap_angle(d[..., 2])
    small = np.abs(th) < 1e-9
    ths = np.where(small, 1.0, th)
    # V^-1 = (th / 2) [[cot(th/2), 1], [-1, cot(th/2)]]
    a = np.where(small, 1.0, 0.5 * ths / np.tan(0.5 * ths))
    b = 0.5 * th
    return np.stack([a * x + b * y, -b * x + a * y, th], axis=-1)


def ref_residuals(poses, edges, z, chart="logmap"):
    """``z^-1 (x_i^-1 x_j)`` by the geometry module, then the chart."""
    d = compose(inverse(z), between(poses[edges[:, 0]], poses[edges[:, 1]]))
    d[..., 2] = wrap_angle(d[..., 2])
    return ref_logmap(d) if chart == "logmap" else d


def ref_rho_weight(s, kernel, k):
    if kernel == "none":
        return s, np.ones_like(s)
    if kernel == "huber":
        d = np.sqrt(s)
        return np.where(d <= k, s, 2 * k * d - k * k), np.where(
            d <= k, 1.0, k / np.maximum(d, 1e-300)
        )
    if kernel == "cauchy":
        return k * k * np.log(1 + s / (k * k)), 1 / (1 + s / (k * k))
    return np.where(s <= k, s, 3 * k - 4 * k * k / (k + s)), np.minimum(1, 2 * k / (k + s)) ** 2


def ref_cost(poses, edges, z, info, kernel="none", k=1.0, mask=None, chart="logmap"):
    e = ref_residuals(poses, edges, z, chart)
    s = np.einsum("ki,kij,kj->k", e, info, e)
    rho, w = ref_rho_weight(s, kernel, k)
    m = np.ones(len(s), bool) if mask is None else mask
    return 0.5 * float(np.where(m, rho, s).sum()), np.where(m, w, 1.0)


def retract(poses, delta):
    """``x Exp(xi)`` with ``delta = (R xi_t, xi_theta)`` (the kernels' coordinates)."""
    out = poses.copy()
    for n, dl in enumerate(delta):
        c, s = math.cos(poses[n, 2]), math.sin(poses[n, 2])
        xi = np.array([c * dl[0] + s * dl[1], -s * dl[0] + c * dl[1], dl[2]])
        w = xi[2]
        V = (
            np.eye(2)
            if abs(w) < 1e-12
            else np.array([[math.sin(w), -(1 - math.cos(w))], [1 - math.cos(w), math.sin(w)]]) / w
        )
        t = V @ xi[:2]
        out[n] = compose(poses[n], np.array([t[0], t[1], w]))
    out[:, 2] = wrap_angle(out[:, 2])
    return out


def numeric_jacobian(poses, edges, z, chart, h=1e-6):
    """Central differences of the reference residuals through the retraction."""
    E, N = len(edges), len(poses)
    J = np.zeros((3 * E, 3 * N))
    for n in range(N):
        for c in range(3):
            d = np.zeros((N, 3))
            d[n, c] = h
            ep = ref_residuals(retract(poses, d), edges, z, chart)
            em = ref_residuals(retract(poses, -d), edges, z, chart)
            diff = ep - em
            diff[:, 2] = wrap_angle(diff[:, 2])
            J[:, 3 * n + c] = (diff / (2 * h)).ravel()
    return J


def random_graph(rng, n=12, extra=10, noise=0.05):
    """A random walk with odometry and random loop closures, noisy measurements and a noisy
    start; information matrices random SPD."""
    truth = np.zeros((n, 3))
    for i in range(1, n):
        truth[i] = compose(
            truth[i - 1], [rng.uniform(0.5, 1.5), rng.normal(0, 0.3), rng.normal(0, 0.8)]
        )
    pairs = [(i, i + 1) for i in range(n - 1)]
    while len(pairs) < n - 1 + extra:
        i, j = sorted(rng.choice(n, 2, replace=False))
        if j != i + 1:
            pairs.append((int(i), int(j)))
    edges = np.array(pairs)
    z = between(truth[edges[:, 0]], truth[edges[:, 1]]) + rng.normal(0, noise, (len(edges), 3))
    A = rng.normal(size=(len(edges), 3, 3))
    info = A @ A.transpose(0, 2, 1) + 3 * np.eye(3)
    start = truth + rng.normal(0, 0.2, truth.shape)
    start[0] = truth[0]
    return truth, start, edges, z, info


# --------------------------------------------------------------------------- residuals & Jacobians


@pytest.mark.parametrize("chart", ["logmap", "xyt"])
def test_residual_kernel_matches_reference(chart):
    rng = np.random.default_rng(1)
    poses = rng.normal(0, 3, (30, 3))
    poses[:, 2] = rng.uniform(-np.pi, np.pi, 30)
    edges = rng.integers(0, 30, (200, 2))
    edges = edges[edges[:, 0] != edges[:, 1]]
    z = rng.normal(0, 2, (len(edges), 3))
    z[:5, 2] = 0.0
    z[5:10] = between(poses[edges[5:10, 0]], poses[edges[5:10, 1]])  # zero residual
    got = edge_residuals(poses, edges, z, chart=chart)
    want = ref_residuals(poses, edges, z, chart)
    dth = wrap_angle(got[:, 2] - want[:, 2])
    assert np.allclose(got[:, :2], want[:, :2], rtol=0, atol=1e-9) and np.abs(dth).max() < 1e-12


@pytest.mark.parametrize("chart", ["logmap", "xyt"])
@pytest.mark.parametrize("scale", [1e-5, 0.3, 2.0, 3.1])
def test_analytic_jacobians_match_numerical(chart, scale):
    rng = np.random.default_rng(int(scale * 1000))
    for _ in range(5):
        poses = rng.normal(0, 2, (2, 3))
        z = between(poses[0], poses[1]) + rng.normal(0, scale, 3)  # residual angle ~ scale
        e = np.empty(3)
        A = np.empty((3, 3))
        B = np.empty((3, 3))
        K.edge_linearize(
            poses, 0, 1, *z, K.CHART_LOGMAP if chart == "logmap" else K.CHART_XYT, e, A, B
        )
        if abs(e[2]) > 3.0:  # too close to the wrap for central differences
            continue
        J = numeric_jacobian(poses, np.array([[0, 1]]), z[None], chart)
        assert np.allclose(np.hstack([A, B]), J, rtol=1e-6, atol=1e-6)


def test_error_equals_gtsam_graph_error():
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(2)
    truth, start, edges, z, info = random_graph(rng, n=15, extra=12, noise=0.3)
    start[:, 2] = rng.uniform(-np.pi, np.pi, len(start))  # far-off headings: large residuals
    g = gtsam.NonlinearFactorGraph()
    v = gtsam.Values()
    for n, p in enumerate(start):
        v.insert(n, gtsam.Pose2(*p))
    for (i, j), zz, om in zip(edges, z, info, strict=True):
        g.add(
            gtsam.BetweenFactorPose2(
                int(i), int(j), gtsam.Pose2(*zz), gtsam.noiseModel.Gaussian.Information(om)
            )
        )
    prior = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))
    g.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(*start[0]), prior))
    ours = graph_error(start, edges, z, info)
    assert ours == pytest.approx(g.error(v), rel=1e-12)


# --------------------------------------------------------------------------- kernels vs numpy


@pytest.mark.parametrize("kernel", ["none", "huber", "cauchy", "dcs"])
def test_normal_equations_kernel_matches_dense_reference(kernel):
    rng = np.random.default_rng(3)
    truth, start, edges, z, info = random_graph(rng, n=10, extra=15, noise=0.4)
    edges = np.vstack([edges, edges[:3]])  # parallel edges share a block
    z = np.vstack([z, z[:3] + 0.1])
    info = np.concatenate([info, info[:3]])
    mask = rng.random(len(edges)) < 0.6
    fixed = np.array([0, 4])
    cfg = OptimizerConfig(robust=kernel, robust_scale=1.5)
    s = _NormalEquations(len(start), edges[:, 0].copy(), edges[:, 1].copy(), fixed)
    data = np.empty(s.nnz)
    rhs = np.empty(3 * s.n_free)
    graph = (
        edges[:, 0].copy(), edges[:, 1].copy(), z, info, K.CHART_LOGMAP,
        {"none": 0, "huber": 1, "cauchy": 2, "dcs": 3}[kernel], cfg.scale, mask,
    )  # fmt: skip
    F = K.accumulate_normal_equations(
        start, graph, s.node_index, s.colptr, s.diag_base, s.edge_base, data, rhs
    )
    import scipy.sparse as sp

    U = sp.csc_matrix((data, s.indices, s.colptr), shape=(3 * s.n_free,) * 2).toarray()
    assert np.allclose(U, np.triu(U))  # upper triangle only
    H = U + np.triu(U, 1).T
    # reference: dense J' W J, W = blockdiag(w_k Omega_k), J by numerical differentiation
    J = numeric_jacobian(start, edges, z, "logmap")
    F_ref, w = ref_cost(start, edges, z, info, kernel, cfg.scale, mask)
    e = ref_residuals(start, edges, z).ravel()
    W = np.zeros((len(e), len(e)))
    for k in range(len(edges)):
        W[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = w[k] * info[k]
    free = np.setdiff1d(np.arange(len(start)), fixed)
    cols = (3 * free[:, None] + np.arange(3)).ravel()
    H_ref = (J.T @ W @ J)[np.ix_(cols, cols)]
    b_ref = (J.T @ W @ e)[cols]
    assert F == pytest.approx(F_ref, rel=1e-12)
    assert np.allclose(H, H_ref, rtol=1e-6, atol=1e-6 * np.abs(H_ref).max())
    assert np.allclose(rhs, b_ref, rtol=1e-6, atol=1e-6 * np.abs(b_ref).max())


@pytest.mark.parametrize("kernel", ["none", "huber", "cauchy", "dcs"])
def test_cost_kernel_and_weights_match_reference(kernel):
    rng = np.random.default_rng(4)
    _, start, edges, z, info = random_graph(rng, n=20, extra=20, noise=1.0)
    mask = rng.random(len(edges)) < 0.5
    chi2 = np.empty(len(edges))
    w = np.empty(len(edges))
    code = {"none": 0, "huber": 1, "cauchy": 2, "dcs": 3}[kernel]
    graph = (edges[:, 0].copy(), edges[:, 1].copy(), z, info, 0, code, 2.0, mask)
    F = K.graph_cost(start, graph, chi2, w)
    F_ref, w_ref = ref_cost(start, edges, z, info, kernel, 2.0, mask)
    assert F == pytest.approx(F_ref, rel=1e-12) and np.allclose(w, w_ref, rtol=1e-12)


@pytest.mark.parametrize("kernel", ["huber", "cauchy", "dcs"])
def test_weight_is_derivative_of_rho(kernel):
    for s in [0.01, 0.5, 0.99, 1.7, 4.0, 30.0, 1e4]:
        h = 1e-6 * s
        rp, _ = K.rho_weight(s + h, {"huber": 1, "cauchy": 2, "dcs": 3}[kernel], 1.3)
        rm, _ = K.rho_weight(s - h, {"huber": 1, "cauchy": 2, "dcs": 3}[kernel], 1.3)
        _, w = K.rho_weight(s, {"huber": 1, "cauchy": 2, "dcs": 3}[kernel], 1.3)
        assert w == pytest.approx((rp - rm) / (2 * h), rel=1e-5)


def test_apply_step_kernel_is_the_exp_retraction():
    rng = np.random.default_rng(5)
    poses = rng.normal(0, 2, (8, 3))
    node_index = np.array([-1, 0, 1, 2, -1, 3, 4, 5])
    delta = rng.normal(0, 0.7, 18)
    delta[2] = 1e-9  # the series branch
    out = np.empty_like(poses)
    K.apply_step(poses, node_index, delta, out)
    d = np.zeros((8, 3))
    d[node_index >= 0] = delta.reshape(-1, 3)
    want = retract(poses, d)
    assert np.allclose(out[:, :2], want[:, :2], atol=1e-12)
    assert np.abs(wrap_angle(out[:, 2] - want[:, 2])).max() < 1e-12
    assert np.array_equal(out[[0, 4]], poses[[0, 4]])


def test_spanning_tree_kernel_matches_python_bfs():
    rng = np.random.default_rng(6)
    n = 60
    pairs = [(int(rng.integers(0, i)), i) for i in range(1, 50)]  # a tree over 0..49
    pairs += [tuple(int(v) for v in rng.choice(50, 2, replace=False)) for _ in range(30)]
    pairs += [(55, 56), (57, 55)]  # a second component, anchored by a fixed node
    edges = np.array(pairs)
    dth = rng.normal(0, 1, len(edges))
    fixed = np.array([0, 56])
    theta = np.full(n, 7.0)
    theta[fixed] = [0.3, -1.0]
    reached = K.spanning_tree(n, edges[:, 0].copy(), edges[:, 1].copy(), dth, fixed, theta)
    # reference: the same breadth-first order (fixed nodes first, edges in adjacency order)
    adj: dict[int, list[tuple[int, int]]] = {v: [] for v in range(n)}
    for k, (i, j) in enumerate(edges):
        adj[int(i)].append((k, int(j)))
        adj[int(j)].append((k, int(i)))
    for v in adj:
        adj[v].sort()
    want = np.full(n, np.nan)
    want[fixed] = [0.3, -1.0]
    queue = list(fixed)
    while queue:
        u = queue.pop(0)
        for k, v in adj[u]:
            if np.isnan(want[v]):
                want[v] = want[u] + (dth[k] if edges[k, 0] == u else -dth[k])
                queue.append(v)
    assert reached == int(np.isfinite(want).sum()) == 53
    assert np.array_equal(np.isnan(theta), np.isnan(want))
    assert np.allclose(theta[~np.isnan(want)], want[~np.isnan(want)], rtol=0, atol=1e-12)


def test_check_edges_kernel_matches_numpy():
    rng = np.random.default_rng(23)
    for _ in range(200):
        e = rng.integers(-1, 12, (6, 2))
        z = rng.normal(size=(6, 3))
        if rng.random() < 0.3:
            z[rng.integers(6), rng.integers(3)] = np.inf
        bad = np.stack(
            [
                (e < 0).any(axis=1) | (e >= 10).any(axis=1),
                e[:, 0] == e[:, 1],
                ~np.isfinite(z).all(axis=1),
            ],
            axis=1,
        )
        k, code = K.check_edges(e[:, 0].copy(), e[:, 1].copy(), 10, z)
        rows = np.flatnonzero(bad.any(axis=1))
        if rows.size == 0:
            assert (k, code) == (-1, 0)
        else:
            assert k == rows[0] and code == 1 + int(np.argmax(bad[rows[0]]))


def test_check_information_kernel_matches_eigenvalues():
    rng = np.random.default_rng(16)
    mats = []
    for _ in range(300):
        A = rng.normal(size=(3, rng.integers(1, 4)))
        M = A @ A.T  # PSD, often singular
        if rng.random() < 0.4:
            M = M - rng.uniform(0.01, 1) * np.eye(3)  # often indefinite
        mats.append(M)
    for M in mats:
        got = K.check_information(M[None], 1e-9)
        low = np.linalg.eigvalsh(M)[0]
        psd = low >= -1e-9 * np.abs(M).max()
        assert (got[1] == 0) == psd, (M, low)
    sym = np.eye(3)[None].copy()
    sym[0, 0, 1] = 1e-3
    assert tuple(K.check_information(sym, 1e-9)) == (0, 2)
    nan = np.eye(3)[None].copy()
    nan[0, 2, 2] = np.nan
    assert tuple(K.check_information(np.concatenate([np.eye(3)[None], nan]), 1e-9)) == (1, 1)


@pytest.mark.parametrize("stage", [0, 1])
def test_lago_assembly_kernel_matches_dense_reference(stage):
    import scipy.sparse as sp

    rng = np.random.default_rng(17)
    truth, start, edges, z, info = random_graph(rng, n=12, extra=10, noise=0.3)
    fixed = np.array([0, 5])
    theta = rng.normal(0, 3, len(start))
    s = _NormalEquations(len(start), edges[:, 0].copy(), edges[:, 1].copy(), fixed)
    data = np.empty(s.nnz)
    rhs = np.empty(3 * s.n_free)
    K.assemble_lago(
        stage, start, theta, edges[:, 0].copy(), edges[:, 1].copy(), z, info,
        s.node_index, s.colptr, s.diag_base, s.edge_base, data, rhs,
    )  # fmt: skip
    U = sp.csc_matrix((data, s.indices, s.colptr), shape=(3 * s.n_free,) * 2).toarray()
    H = U + np.triu(U, 1).T
    # dense reference: J' W J and J' W r of the stage's linear residuals u_j - u_i - r
    n = len(start)
    dim, lo = (1, 2) if stage == 0 else (2, 0)
    J = np.zeros((dim * len(edges), dim * n))
    W = np.zeros((dim * len(edges),) * 2)
    r = np.zeros(dim * len(edges))
    for k, (i, j) in enumerate(edges):
        rows = slice(dim * k, dim * k + dim)
        J[rows, dim * j : dim * j + dim] = np.eye(dim)
        J[rows, dim * i : dim * i + dim] = -np.eye(dim)
        if stage == 0:
            w = 1.0 / np.linalg.inv(info[k])[2, 2]
            diff = theta[j] - theta[i]
            ell = np.round((diff - z[k, 2]) / (2 * np.pi))
            W[rows, rows] = w
            r[rows] = z[k, 2] + 2 * np.pi * ell - diff
        else:
            c, sn = np.cos(theta[i]), np.sin(theta[i])
            R = np.array([[c, -sn], [sn, c]])
            W[rows, rows] = R @ info[k][:2, :2] @ R.T
            r[rows] = R @ z[k, :2] - (start[j, :2] - start[i, :2])
    free = np.setdiff1d(np.arange(n), fixed)
    cols = (dim * free[:, None] + np.arange(dim)).ravel()
    H_ref = (J.T @ W @ J)[np.ix_(cols, cols)]
    g_ref = (J.T @ W @ r)[cols]
    idx = (3 * np.arange(len(free))[:, None] + lo + np.arange(dim)).ravel()
    assert np.allclose(H[np.ix_(idx, idx)], H_ref, rtol=1e-10, atol=1e-9)
    assert np.allclose(rhs[idx], g_ref, rtol=1e-10, atol=1e-9)
    other = np.setdiff1d(np.arange(3 * len(free)), idx)
    assert np.array_equal(H[np.ix_(other, other)], np.eye(other.size))
    assert np.all(H[np.ix_(other, idx)] == 0) and np.all(rhs[other] == 0)


def ref_structure(ei, ej, node_index):
    """The block pattern by numpy set operations (np.unique), as the kernel's reference."""
    nf = int((node_index >= 0).sum())
    p, q = node_index[ei], node_index[ej]
    both = (p >= 0) & (q >= 0)
    uniq, inv = np.unique(np.maximum(p, q)[both] * nf + np.minimum(p, q)[both], return_inverse=True)
    ucol, urow = uniq // nf, uniq % nf
    blk_colptr = np.concatenate([[0], np.cumsum(np.bincount(ucol, minlength=nf))])
    nb = np.diff(blk_colptr)
    colptr = np.concatenate([[0], np.cumsum((3 * nb[:, None] + np.arange(1, 4)).ravel())])
    indices = []
    for c in range(nf):
        for k in range(3):
            for r in urow[blk_colptr[c] : blk_colptr[c + 1]]:
                indices += [3 * r, 3 * r + 1, 3 * r + 2]
            indices += [3 * c + r for r in range(k + 1)]
    edge_base = np.full(len(ei), -1)
    edge_base[both] = 3 * (np.arange(uniq.size) - blk_colptr[ucol])[inv.ravel()]
    cols = np.arange(3 * nf)
    diag_pos = colptr[cols] + 3 * nb[cols // 3] + cols % 3
    return colptr, np.array(indices), 3 * nb, edge_base, diag_pos, blk_colptr, urow


def test_structure_kernel_matches_numpy_reference():
    rng = np.random.default_rng(19)
    _, _, edges, _, _ = random_graph(rng, n=30, extra=40)
    edges = np.vstack([edges, edges[:5], edges[5:8, ::-1]])  # parallel and reversed edges
    node_index = np.full(30, -1)
    free = np.setdiff1d(np.arange(30), [0, 3, 17])
    node_index[free] = rng.permutation(free.size)  # any elimination order
    got = K.build_structure(edges[:, 0].copy(), edges[:, 1].copy(), node_index)
    want = ref_structure(edges[:, 0], edges[:, 1], node_index)
    for a, b in zip(got, want, strict=True):
        assert np.array_equal(a, b)


def test_number_free_nodes_kernel_matches_numpy():
    fixed = np.array([3, 0, 3, 7])
    node_index, nf = K.number_free_nodes(10, fixed)
    want = np.full(10, -1)
    free = np.setdiff1d(np.arange(10), fixed)
    want[free] = np.arange(free.size)
    assert nf == free.size and np.array_equal(node_index, want)


def ref_etree(blk_colptr, blk_rows):
    """Elimination tree by definition: parent(j) = the first off-diagonal row of column j of
    the Cholesky factor, from a dense symbolic elimination."""
    n = blk_colptr.size - 1
    S = np.eye(n, dtype=bool)
    for c in range(n):
        S[blk_rows[blk_colptr[c] : blk_colptr[c + 1]], c] = True
    S = S | S.T
    L = np.zeros((n, n), dtype=bool)
    for j in range(n):  # column j of L: rows of S[:, j] below j, plus fill from earlier columns
        col = S[j + 1 :, j].copy()
        for k in range(j):
            if L[j, k]:
                col |= L[j + 1 :, k]
        L[j + 1 :, j] = col
    parent = np.array([np.flatnonzero(L[:, j])[0] if L[:, j].any() else -1 for j in range(n)])
    return parent, L.sum(axis=0)


def random_block_system(rng, n_nodes=40, extra=50, fixed=(0,)):
    _, start, edges, z, info = random_graph(rng, n=n_nodes, extra=extra, noise=0.3)
    ei, ej = edges[:, 0].copy(), edges[:, 1].copy()
    s = _NormalEquations(n_nodes, ei, ej, np.array(fixed))
    data, rhs = np.empty(s.nnz), np.empty(3 * s.n_free)
    graph = (ei, ej, z, info, 0, 0, 1.0, np.ones(len(ei), bool))
    K.accumulate_normal_equations(
        start, graph, s.node_index, s.colptr, s.diag_base, s.edge_base, data, rhs
    )
    return s, data, rhs


@pytest.mark.parametrize("n_nodes", [10, 120])  # natural order and a fill-reducing one
def test_ldl_symbolic_kernel_matches_dense_elimination(n_nodes):
    s, _, _ = random_block_system(np.random.default_rng(24), n_nodes=n_nodes, extra=n_nodes)
    etree, Lp = K.ldl_symbolic(s.blk_colptr, s.blk_rows)
    parent, counts = ref_etree(s.blk_colptr, s.blk_rows)
    assert np.array_equal(etree, parent) and np.array_equal(np.diff(Lp), counts)


@pytest.mark.parametrize("n_nodes", [10, 120])
def test_ldl_factor_and_solve_match_numpy(n_nodes):
    import scipy.sparse as sp

    rng = np.random.default_rng(25)
    s, data, rhs = random_block_system(rng, n_nodes=n_nodes, extra=n_nodes)
    n3 = 3 * s.n_free
    damp = rng.uniform(0.5, 2.0, n3)
    lam = 0.1
    nnz = s.Lp[-1]
    Li, Lx, Dinv = np.empty(nnz, np.int64), np.empty((nnz, 3, 3)), np.empty((s.n_free, 3, 3))
    ok = K.ldl_factor(
        data, s.colptr, s.diag_base, s.blk_colptr, s.blk_rows, s.etree, s.Lp, lam, damp, Li,
        Lx, Dinv,
    )  # fmt: skip
    assert ok
    U = sp.csc_matrix((data, s.indices, s.colptr), shape=(n3, n3)).toarray()
    H = U + np.triu(U, 1).T + lam * np.diag(damp)
    x = np.empty(n3)
    K.ldl_solve(s.Lp, Li, Lx, Dinv, rhs, x)
    assert np.allclose(x, np.linalg.solve(H, rhs), rtol=1e-9, atol=1e-12 * np.abs(x).max())
    # the factors themselves: L D L' = H
    L = np.eye(n3)
    for c in range(s.n_free):
        for q in range(s.Lp[c], s.Lp[c + 1]):
            L[3 * Li[q] : 3 * Li[q] + 3, 3 * c : 3 * c + 3] = Lx[q]
    D = np.zeros((n3, n3))
    for k in range(s.n_free):
        D[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = np.linalg.inv(Dinv[k])
    assert np.allclose(L @ D @ L.T, H, rtol=1e-9, atol=1e-9 * np.abs(H).max())


def test_ldl_factor_reports_an_indefinite_matrix():
    s, data, _ = random_block_system(np.random.default_rng(26), n_nodes=8, extra=6)
    nnz = s.Lp[-1]
    args = (np.empty(nnz, np.int64), np.empty((nnz, 3, 3)), np.empty((s.n_free, 3, 3)))
    damp = np.ones(3 * s.n_free)
    common = (data, s.colptr, s.diag_base, s.blk_colptr, s.blk_rows, s.etree, s.Lp)
    assert K.ldl_factor(*common, 0.0, damp, *args)
    assert not K.ldl_factor(*common, -1e6, damp, *args)


def test_fill_reducing_order_gives_the_same_solution(monkeypatch):
    import probmap.slam.posegraph.optimize as pg

    rng = np.random.default_rng(22)
    _, start, edges, z, info = random_graph(rng, n=150, extra=150, noise=0.1)
    mask = edges[:, 1] != edges[:, 0] + 1
    cfg = OptimizerConfig(robust="dcs")
    ordered = optimize_pose_graph(start, edges, z, info, cfg, robust_mask=mask, init="lago")
    s_ord = _NormalEquations(150, edges[:, 0].copy(), edges[:, 1].copy(), np.array([0]))
    monkeypatch.setattr(pg, "_ORDERING_MIN_FREE", 10**9)
    natural = optimize_pose_graph(start, edges, z, info, cfg, robust_mask=mask, init="lago")
    assert ordered.iterations == natural.iterations and ordered.message == natural.message
    assert ordered.final_error == pytest.approx(natural.final_error, rel=1e-9)
    assert np.allclose(ordered.poses, natural.poses, atol=1e-8)
    s_nat_lp = K.ldl_symbolic(
        *K.build_structure(edges[:, 0].copy(), edges[:, 1].copy(), np.arange(150) - 1)[5:]
    )[1]
    assert s_ord.Lp[-1] < s_nat_lp[-1]  # the ordering reduces fill


# --------------------------------------------------------------------------- LM


def test_linear_problem_matches_closed_form():
    """Poses on the x axis with measurements along x and diagonal information: headings and
    y stay 0 (their gradient vanishes and H decouples), so LM must return the weighted linear
    least-squares solution of the x coordinates, computed here with numpy."""
    rng = np.random.default_rng(7)
    n = 25
    pairs = [(i, i + 1) for i in range(n - 1)] + [
        tuple(sorted(rng.choice(n, 2, replace=False))) for _ in range(30)
    ]
    edges = np.array(pairs)
    dx = rng.normal(1.0, 0.5, len(edges)) * (edges[:, 1] - edges[:, 0])
    z = np.stack([dx, np.zeros(len(edges)), np.zeros(len(edges))], axis=1)
    wx = rng.uniform(1, 50, len(edges))
    info = np.zeros((len(edges), 3, 3))
    info[:, 0, 0] = wx
    info[:, 1, 1] = rng.uniform(1, 50, len(edges))
    info[:, 2, 2] = rng.uniform(1, 50, len(edges))
    start = np.zeros((n, 3))
    start[:, 0] = np.arange(n) * 0.7
    # closed form: minimise sum w (x_j - x_i - dx)^2 with x_0 = 0
    A = np.zeros((len(edges), n))
    A[np.arange(len(edges)), edges[:, 1]] = 1.0
    A[np.arange(len(edges)), edges[:, 0]] = -1.0
    sw = np.sqrt(wx)
    x_free, *_ = np.linalg.lstsq(A[:, 1:] * sw[:, None], dx * sw, rcond=None)
    r = optimize_pose_graph(start, edges, z, info)
    assert r.converged
    assert np.allclose(r.poses[1:, 0], x_free, rtol=0, atol=1e-9)
    assert np.abs(r.poses[:, 1:]).max() < 1e-12
    resid = A[:, 1:] @ x_free - dx
    assert r.final_error == pytest.approx(0.5 * float(wx @ resid**2), rel=1e-9)


def test_consistent_graph_reaches_zero_error_from_noisy_start():
    rng = np.random.default_rng(8)
    truth, start, edges, z, info = random_graph(rng, n=30, extra=20, noise=0.0)
    r = optimize_pose_graph(start, edges, z, info)
    assert r.converged and r.final_error < 1e-16
    assert np.allclose(r.poses[:, :2], truth[:, :2], atol=1e-8)
    assert np.abs(wrap_angle(r.poses[:, 2] - truth[:, 2])).max() < 1e-8
    assert r.initial_error > 1.0 and np.all(r.weights == 1.0)


def _gtsam_optimize(gtsam, start, edges, z, info):
    g = gtsam.NonlinearFactorGraph()
    v = gtsam.Values()
    for n, p in enumerate(start):
        v.insert(n, gtsam.Pose2(*p))
    for (i, j), zz, om in zip(edges, z, info, strict=True):
        g.add(
            gtsam.BetweenFactorPose2(
                int(i), int(j), gtsam.Pose2(*zz), gtsam.noiseModel.Gaussian.Information(om)
            )
        )
    prior = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))
    g.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(*start[0]), prior))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-14)
    res = gtsam.LevenbergMarquardtOptimizer(g, v, params).optimize()
    return g.error(res), np.array(
        [
            [res.atPose2(n).x(), res.atPose2(n).y(), res.atPose2(n).theta()]
            for n in range(len(start))
        ]
    )


def test_lm_matches_gtsam_on_a_random_graph():
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(9)
    truth, start, edges, z, info = random_graph(rng, n=40, extra=30, noise=0.05)
    F_g, poses_g = _gtsam_optimize(gtsam, start, edges, z, info)
    r = optimize_pose_graph(start, edges, z, info)
    assert r.converged
    assert r.final_error == pytest.approx(F_g, rel=1e-6)
    assert np.allclose(r.poses[:, :2], poses_g[:, :2], atol=1e-5)


@pytest.mark.realdata
@pytest.mark.parametrize("name", ["pose2example.txt", "noisyToyGraph.txt", "w100.graph"])
def test_lm_matches_gtsam_on_small_standard_graphs(shared_data, name):
    """GTSAM's default LM on GTSAM's own example graphs: the same final error to 1e-6."""
    gtsam = pytest.importorskip("gtsam")
    from probmap.datasets.g2o import pose_graph_arrays, read_pose_graph

    path = shared_data(f"pose-graphs/{name}")
    a = pose_graph_arrays(read_pose_graph(path))
    fmt = (
        gtsam.NoiseFormat.NoiseFormatAUTO
        if name.endswith(".graph")
        else gtsam.NoiseFormat.NoiseFormatG2O
    )
    g, v = gtsam.load2D(str(path), None, 0, False, True, fmt)
    g.add(
        gtsam.PriorFactorPose2(
            0, v.atPose2(0), gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))
        )
    )
    opt = gtsam.LevenbergMarquardtOptimizer(g, v, gtsam.LevenbergMarquardtParams())
    F_g = g.error(opt.optimize())
    r = optimize_pose_graph(a.poses, a.edges, a.measurements, a.information)
    assert graph_error(a.poses, a.edges, a.measurements, a.information) == pytest.approx(
        g.error(v), rel=1e-12
    )
    assert r.converged and r.final_error == pytest.approx(F_g, rel=1e-6)


@pytest.mark.realdata
def test_lago_start_beats_gtsam_where_gtsam_hits_its_cap(shared_data):
    """INTEL_P_toro: GTSAM's default LM stops at 100 iterations at 35485.4 (data README)."""
    from probmap.datasets.g2o import pose_graph_arrays, read_pose_graph

    a = pose_graph_arrays(read_pose_graph(shared_data("pose-graphs/INTEL_P_toro.graph")))
    r = optimize_pose_graph(a.poses, a.edges, a.measurements, a.information, init="lago")
    assert r.initial_error == pytest.approx(2.90748e6, rel=1e-5)
    assert r.converged and r.final_error < 200.0 < 35485.4


# --------------------------------------------------------------------------- robust costs


def _loop_with_false_closure(false_closure=True):
    """A 61-pose loop (a 7.5 m square, 0.5 m steps) with odometry noise of 2 mm and 0.5 mrad
    per step, true loop closures (sigma 3 cm, 0.6 deg) where the loop meets itself, and one
    false closure, as confident as the true ones, that puts pose 45 (the opposite corner,
    10.6 m away) 1 m ahead of pose 15."""
    rng = np.random.default_rng(10)
    steps = []
    for _ in range(4):
        steps += [[0.5, 0.0, 0.0]] * 14 + [[0.5, 0.0, np.pi / 2]]
    truth = np.zeros((61, 3))
    for i, s in enumerate(steps):
        truth[i + 1] = compose(truth[i], s)
    sigma = np.array([0.002, 0.002, 0.0005])
    edges = np.array([(i, i + 1) for i in range(60)] + [(0, 60), (1, 59), (2, 58), (58, 0)])
    z = between(truth[edges[:, 0]], truth[edges[:, 1]])
    z[:60] += rng.normal(0, sigma, (60, 3))
    info = np.concatenate(
        [np.tile(np.diag(sigma**-2.0), (60, 1, 1)), np.tile(np.diag([1e3, 1e3, 1e4]), (4, 1, 1))]
    )
    if false_closure:
        edges = np.vstack([edges, [15, 45]])
        z = np.vstack([z, [1.0, 0.0, 0.0]])
        info = np.concatenate([info, np.diag([1e3, 1e3, 1e4])[None]])
    closure = np.zeros(len(edges), bool)
    closure[60:] = True
    start = np.zeros_like(truth)
    for i in range(60):
        start[i + 1] = compose(start[i], z[i])
    return truth, start, edges, z, info, closure


def _aligned_error(poses, truth):
    return float(np.linalg.norm(poses[:, :2] - truth[:, :2], axis=1).max())


@pytest.mark.parametrize("kernel", ["cauchy", "dcs", "huber"])
def test_robust_kernel_rejects_a_false_loop_closure(kernel):
    truth, start, edges, z, info, closure = _loop_with_false_closure()
    clean = optimize_pose_graph(start, edges[:-1], z[:-1], info[:-1])  # without the outlier
    plain = optimize_pose_graph(start, edges, z, info)
    cfg = OptimizerConfig(robust=kernel)
    r = optimize_pose_graph(start, edges, z, info, cfg, robust_mask=closure)
    assert _aligned_error(clean.poses, truth) < 0.04  # what the noise allows
    assert _aligned_error(plain.poses, truth) > 1.0  # least squares bends the loop by metres
    assert _aligned_error(r.poses, truth) < 0.05  # the robust cost does not
    # and it lands on the outlier-free solution (Huber, not redescending, keeps a pull)
    assert _aligned_error(r.poses, clean.poses) < (0.01 if kernel == "huber" else 0.001)
    assert r.weights[-1] < 0.01 and np.all(r.weights[60:-1] > 0.9)
    assert np.all(r.weights[:60] == 1.0)  # odometry stays quadratic


def test_robust_kernel_on_all_edges_still_finds_the_loop():
    truth, start, edges, z, info, _ = _loop_with_false_closure()
    r = optimize_pose_graph(start, edges, z, info, OptimizerConfig(robust="cauchy"))
    assert _aligned_error(r.poses, truth) < 0.05


# --------------------------------------------------------------------------- LAGO


def test_lago_is_exact_on_a_consistent_graph_and_wraps_headings():
    rng = np.random.default_rng(11)
    truth, _, edges, z, info = random_graph(rng, n=40, extra=25, noise=0.0)
    got = lago_initialization(np.zeros_like(truth), edges, z, info)
    assert np.allclose(got[:, :2], truth[:, :2], atol=1e-8)
    assert np.abs(wrap_angle(got[:, 2] - truth[:, 2])).max() < 1e-9
    assert np.all((got[:, 2] >= -np.pi) & (got[:, 2] < np.pi))


def test_lago_start_finds_the_optimum_from_random_headings():
    rng = np.random.default_rng(12)
    truth, start, edges, z, info = random_graph(rng, n=60, extra=40, noise=0.02)
    start[1:, 2] = rng.uniform(-np.pi, np.pi, len(start) - 1)
    best = optimize_pose_graph(truth, edges, z, info)
    r = optimize_pose_graph(start, edges, z, info, init="lago")
    assert r.final_error == pytest.approx(best.final_error, rel=1e-6)
    assert r.initial_error == pytest.approx(graph_error(start, edges, z, info))


def test_lago_keeps_several_fixed_nodes():
    rng = np.random.default_rng(13)
    truth, start, edges, z, info = random_graph(rng, n=20, extra=10, noise=0.0)
    got = lago_initialization(truth, edges, z, info, fixed=[0, 7])
    assert np.array_equal(got[[0, 7]], truth[[0, 7]])
    assert np.allclose(got[:, :2], truth[:, :2], atol=1e-8)


# --------------------------------------------------------------------------- class tier


def test_class_matches_function_tier_and_grows():
    rng = np.random.default_rng(14)
    truth, start, edges, z, info = random_graph(rng, n=80, extra=60, noise=0.03)
    mask = edges[:, 1] != edges[:, 0] + 1
    cfg = OptimizerConfig(robust="cauchy")
    g = PoseGraph2D(cfg)
    for p in start:
        g.add_node(p)
    for (i, j), zz, om, m in zip(edges, z, info, mask, strict=True):
        g.add_edge(int(i), int(j), zz, om, robust=bool(m))
    assert (g.num_nodes, g.num_edges) == (80, len(edges))
    assert g.error() == pytest.approx(graph_error(start, edges, z, info, cfg, robust_mask=mask))
    r1 = g.optimize()
    r2 = optimize_pose_graph(start, edges, z, info, cfg, robust_mask=mask)
    assert r1.final_error == pytest.approx(r2.final_error, rel=1e-12)
    assert np.array_equal(g.poses, r1.poses) and np.array_equal(g.robust_mask, mask)
    assert g.error() == pytest.approx(r1.final_error)
    # warm start: a second call has nothing left to do
    r3 = g.optimize()
    assert r3.iterations <= 2 and r3.final_error <= r1.final_error * (1 + 1e-12)


def test_class_incremental_optimization():
    """Add nodes and edges, optimize every 20 nodes, as a SLAM front end would."""
    rng = np.random.default_rng(15)
    truth, _, edges, z, info = random_graph(rng, n=100, extra=0, noise=0.01)
    g = PoseGraph2D()
    g.add_node(truth[0])
    for i in range(1, 100):
        g.add_node(compose(g.poses[i - 1], z[i - 1]))
        g.add_edge(i - 1, i, z[i - 1], info[i - 1])
        if i % 10 == 0 and i >= 20:  # a loop closure to a node 20 back
            j = i - 20
            g.add_edge(j, i, between(truth[j], truth[i]), np.eye(3) * 100.0)
        if i % 20 == 0:
            r = g.optimize()
            assert r.converged and r.final_error <= r.initial_error
    assert g.num_nodes == 100 and g.edges.shape == (g.num_edges, 2)
    assert np.array_equal(g.pose(7), g.poses[7]) and np.array_equal(g.pose(-1), g.poses[-1])
    with pytest.raises(IndexError):
        g.pose(100)


def test_class_validation():
    g = PoseGraph2D()
    with pytest.raises(ValueError, match="no nodes"):
        g.optimize()
    a = g.add_node([0, 0, 0])
    b = g.add_node([1, 0, 0])
    with pytest.raises(ValueError, match="pose must be"):
        g.add_node([0, 0])
    with pytest.raises(ValueError, match="lie in"):
        g.add_edge(a, 5, [1, 0, 0], np.eye(3))
    with pytest.raises(ValueError, match="itself"):
        g.add_edge(a, a, [1, 0, 0], np.eye(3))
    with pytest.raises(ValueError, match="not connected"):
        g.optimize()
    g.add_edge(a, b, [1, 0, 0], np.eye(3))
    g.poses = np.array([[0, 0, 0], [2, 0, 0]])
    assert g.optimize().final_error < 1e-20


# --------------------------------------------------------------------------- validation


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"max_iterations": -1}, "max_iterations"),
        ({"max_iterations": 2.5}, "max_iterations"),
        ({"relative_tolerance": float("nan")}, "relative_tolerance"),
        ({"initial_lambda": 0.0}, "initial_lambda"),
        ({"initial_lambda": 1.0, "max_lambda": 0.5}, "max_lambda"),
        ({"robust": "tukey"}, "robust"),
        ({"robust": "huber", "robust_scale": -1.0}, "robust_scale"),
        ({"damping": "none"}, "damping"),
        ({"chart": "expmap"}, "chart"),
    ],
)
def test_config_validation(kw, match):
    with pytest.raises(ValueError, match=match):
        OptimizerConfig(**kw)


def test_config_resolves_default_scales():
    assert OptimizerConfig(robust="huber").scale == 1.345
    assert OptimizerConfig(robust="dcs").scale == 1.0
    assert OptimizerConfig(robust="cauchy", robust_scale=3.0).scale == 3.0


def test_function_tier_validation():
    poses = np.zeros((3, 3))
    edges = np.array([[0, 1], [1, 2]])
    z = np.zeros((2, 3))
    info = np.tile(np.eye(3), (2, 1, 1))
    with pytest.raises(ValueError, match=r"poses must have shape"):
        optimize_pose_graph(np.zeros((3, 2)), edges, z, info)
    with pytest.raises(ValueError, match="integer"):
        optimize_pose_graph(poses, edges.astype(float), z, info)
    with pytest.raises(ValueError, match="measurements must have shape"):
        optimize_pose_graph(poses, edges, z[:1], info)
    with pytest.raises(ValueError, match="measurement of edge 1 is not finite"):
        optimize_pose_graph(poses, edges, np.array([[0, 0, 0], [0, np.nan, 0.0]]), info)
    bad = info.copy()
    bad[1, 0, 1] = 0.5
    with pytest.raises(ValueError, match="edge 1 is not symmetric"):
        optimize_pose_graph(poses, edges, z, bad)
    bad = info.copy()
    bad[0] = np.diag([1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match="edge 0 is not positive semi-definite"):
        optimize_pose_graph(poses, edges, z, bad)
    with pytest.raises(ValueError, match="at least one node must be fixed"):
        optimize_pose_graph(poses, edges, z, info, fixed=[])
    with pytest.raises(ValueError, match="robust_mask"):
        optimize_pose_graph(poses, edges, z, info, robust_mask=[1, 0])
    with pytest.raises(ValueError, match="init"):
        optimize_pose_graph(poses, edges, z, info, init="chordal")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="not connected"):
        optimize_pose_graph(np.zeros((4, 3)), edges, z, info)
    r = optimize_pose_graph(poses, edges, z, info, fixed=[0, 1, 2])
    assert r.converged and r.iterations == 0 and r.message == "nothing to optimize"


def test_write_pose_graph_g2o_round_trip(tmp_path):
    from probmap.datasets.g2o import pose_graph_arrays, read_pose_graph

    rng = np.random.default_rng(18)
    _, start, edges, z, info = random_graph(rng, n=10, extra=5)
    out = write_pose_graph_g2o(tmp_path / "g.g2o", start, edges, z, info, ids=np.arange(10) * 2)
    a = pose_graph_arrays(read_pose_graph(out))
    assert a.ids.tolist() == list(range(0, 20, 2))
    assert np.array_equal(a.poses, start) and np.array_equal(a.edges, edges)
    assert np.array_equal(a.measurements, z)
    assert np.allclose(a.information, info, rtol=1e-15, atol=0)
    assert [p.name for p in tmp_path.iterdir()] == ["g.g2o"]


def test_core_module_does_not_import_datasets_pipelines_or_cli():
    import subprocess
    import sys

    code = (
        "import sys, probmap.slam.posegraph.optimize as pg; import numpy as np; "
        "pg.optimize_pose_graph(np.zeros((2, 3)), [[0, 1]], [[1.0, 0, 0]], [np.eye(3)], init='lago'); "
        "print(sorted(m for m in sys.modules if m.startswith(('probmap.datasets', "
        "'probmap.pipelines', 'probmap.cli'))))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_an_edge_with_zero_information_pulls_nothing_and_can_be_restored():
    """set_information: a loop closure left out (zero information) leaves the optimum of the
    rest of the graph; given its information back, it pulls again."""
    from probmap.slam.posegraph.optimize import PoseGraph2D

    def square(wrong_closure: bool) -> PoseGraph2D:
        g = PoseGraph2D()
        truth = [(0.0, 0.0, 0.0), (1.0, 0.0, np.pi / 2), (1.0, 1.0, np.pi), (0.0, 1.0, -np.pi / 2)]
        for p in truth:
            g.add_node(np.asarray(p) + 0.05)
        for i in range(3):
            g.add_edge(i, i + 1, (1.0, 0.0, np.pi / 2), np.eye(3) * 100.0)
        if wrong_closure:  # the closure 3 -> 0 measured 0.5 m off
            g.add_edge(3, 0, (1.5, 0.0, np.pi / 2), np.eye(3) * 100.0)
        return g

    chain = square(False)
    chain.optimize(20)
    g = square(True)
    g.set_information([3], np.zeros((3, 3)))
    g.optimize(20)
    np.testing.assert_allclose(g.poses, chain.poses, atol=1e-9)
    g.set_information([3], np.eye(3) * 100.0)
    g.optimize(20)
    assert np.abs(g.poses - chain.poses).max() > 0.05  # the closure pulls again
    with pytest.raises(ValueError, match="edge indices"):
        g.set_information([4], np.eye(3))
    with pytest.raises(ValueError, match="finite"):
        g.set_information([0], np.full((3, 3), np.nan))
