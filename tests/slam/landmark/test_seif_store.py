"""The SEIF's block-sparse information store against a dense matrix (pure-Python reference)."""

from __future__ import annotations

import numpy as np

from probmap.slam.landmark._seif_store import InformationStore


def _random_store(rng: np.random.Generator, n: int = 7):
    """A store and the dense Omega, xi, mu it should represent."""
    d = 3 + 2 * n
    A = rng.standard_normal((d, d))
    dense = A @ A.T + d * np.eye(d)
    # sparsity: robot links only to landmarks 0..2, landmark links only between neighbours
    for i in range(n):
        for j in range(n):
            if abs(i - j) > 1:
                dense[3 + 2 * i : 5 + 2 * i, 3 + 2 * j : 5 + 2 * j] = 0.0
        if i > 2:
            dense[:3, 3 + 2 * i : 5 + 2 * i] = 0.0
            dense[3 + 2 * i : 5 + 2 * i, :3] = 0.0
    xi = rng.standard_normal(d)
    mu = rng.standard_normal(d)
    st = InformationStore(np.eye(3), np.zeros(3), np.zeros(3), capacity=2)
    for i in range(n):
        st.add_landmark(mu[3 + 2 * i : 5 + 2 * i])
    st.scatter(list(range(n)), dense, xi, mu)
    return st, dense, xi, mu


def test_scatter_then_sparse_equals_dense():
    st, dense, xi, mu = _random_store(np.random.default_rng(0))
    assert np.allclose(st.to_sparse().toarray(), dense)
    assert np.allclose(st.xi_vector(), xi)
    assert np.allclose(st.mu_vector(), mu)
    counts = st.block_counts()
    assert counts == {"robot_links": 3, "landmarks": 7, "landmark_links": 6}
    assert st.state_nbytes() == 8 * (15 + 8 * 7 + 4 * 6 + 6 * 3)


def test_gather_is_the_dense_submatrix_and_boundary_the_rest():
    st, dense, xi, mu = _random_store(np.random.default_rng(1))
    slots = [4, 1, 2]
    rows = np.concatenate([np.arange(3)] + [3 + 2 * s + np.arange(2) for s in slots])
    O, x, m = st.gather(slots)
    assert np.allclose(O, dense[np.ix_(rows, rows)])
    assert np.allclose(x, xi[rows])
    assert np.allclose(m, mu[rows])
    outside = np.setdiff1d(np.arange(dense.shape[0]), rows)
    ref = dense[np.ix_(rows[3:], outside)] @ mu[outside]
    assert np.allclose(st.boundary(slots), ref)


def test_zero_blocks_are_deleted_on_scatter():
    st, dense, xi, mu = _random_store(np.random.default_rng(2))
    O, x, m = st.gather([0, 1])
    O[:3, 3:5] = 0.0
    O[3:5, :3] = 0.0
    O[3:5, 5:7] = 0.0
    O[5:7, 3:5] = 0.0
    st.scatter([0, 1], O, x, m)
    assert 0 not in st.robot_links
    assert st.link(0, 1) is None and 0 not in st.adjacency[1]
    assert st.link(1, 2) is not None
    assert np.allclose(st.link(2, 1), st.link(1, 2).T)


def test_growth_keeps_values():
    st = InformationStore(np.eye(3), np.zeros(3), np.zeros(3), capacity=4)
    for i in range(50):
        st.add_landmark(np.array([i, -i], dtype=float))
    assert st.n == 50
    assert np.allclose(st.mu_landmarks[:, 0], np.arange(50))
