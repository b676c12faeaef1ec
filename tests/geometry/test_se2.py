import numpy as np
import pytest

from probmap.geometry import se2


def num_jac(f, x, eps=1e-6):
    x = np.asarray(x, dtype=float)
    f0 = np.asarray(f(x))
    J = np.zeros((f0.size, x.size))
    for i in range(x.size):
        dx = np.zeros_like(x)
        dx[i] = eps
        d = (np.asarray(f(x + dx)) - np.asarray(f(x - dx))) / (2 * eps)
        J[:, i] = d.ravel()
    return J


def rand_pose(rng, n=None):
    shape = (3,) if n is None else (n, 3)
    p = rng.uniform(-5, 5, size=shape)
    p[..., 2] = rng.uniform(-np.pi, np.pi, size=shape[:-1])
    return p


def test_wrap_angle_range_and_identity():
    a = np.linspace(-20, 20, 1001)
    w = se2.wrap_angle(a)
    assert np.all(w >= -np.pi) and np.all(w < np.pi)
    assert np.allclose(np.cos(w), np.cos(a)) and np.allclose(np.sin(w), np.sin(a))


def test_compose_matches_homogeneous_matrices():
    rng = np.random.default_rng(0)

    def mat(p):
        c, s = np.cos(p[2]), np.sin(p[2])
        return np.array([[c, -s, p[0]], [s, c, p[1]], [0, 0, 1]])

    for _ in range(20):
        a, b = rand_pose(rng), rand_pose(rng)
        M = mat(a) @ mat(b)
        c = se2.compose(a, b)
        assert np.allclose(mat(c), M)


def test_inverse_between_round_trip_vectorised():
    rng = np.random.default_rng(1)
    a, b = rand_pose(rng, 50), rand_pose(rng, 50)
    ident = se2.compose(a, se2.inverse(a))
    assert np.allclose(ident, 0, atol=1e-12)
    rel = se2.between(a, b)
    assert np.allclose(rel, se2.compose(se2.inverse(a), b))
    back = se2.compose(a, rel)
    assert np.allclose(back[:, :2], b[:, :2])
    assert np.allclose(se2.wrap_angle(back[:, 2] - b[:, 2]), 0, atol=1e-12)


def test_transform_point_matches_compose():
    rng = np.random.default_rng(2)
    a = rand_pose(rng)
    p = rng.normal(size=2)
    assert np.allclose(se2.transform_point(a, p), se2.compose(a, [p[0], p[1], 0.0])[:2])


@pytest.mark.parametrize("seed", range(5))
def test_jacobians_match_numerical(seed):
    rng = np.random.default_rng(seed)
    a, b = rand_pose(rng), rand_pose(rng)
    a[2], b[2] = 0.3, -0.4  # keep the sum away from the wrap discontinuity
    J_a, J_b = se2.compose_jacobians(a, b)
    assert np.allclose(J_a, num_jac(lambda x: se2.compose(x, b), a), atol=1e-6)
    assert np.allclose(J_b, num_jac(lambda x: se2.compose(a, x), b), atol=1e-6)
    assert np.allclose(se2.inverse_jacobian(a), num_jac(se2.inverse, a), atol=1e-6)
    B_a, B_b = se2.between_jacobians(a, b)
    assert np.allclose(B_a, num_jac(lambda x: se2.between(x, b), a), atol=1e-6)
    assert np.allclose(B_b, num_jac(lambda x: se2.between(a, x), b), atol=1e-6)


def test_bad_shape_raises():
    with pytest.raises(ValueError, match="shape"):
        se2.compose([1.0, 2.0], [0.0, 0.0, 0.0])


def test_pose_batch_checks_and_passes_contiguous_arrays_through():
    """The one pose-batch check (MCL's and the range-finder models' poses, the pose graph's)."""
    p = np.arange(6.0).reshape(2, 3)
    assert se2.pose_batch(p) is p  # already C-contiguous float64: no copy
    q = se2.pose_batch([[1, 2, 3]])
    assert q.dtype == np.float64 and q.flags.c_contiguous and q.tolist() == [[1.0, 2.0, 3.0]]
    t = np.asfortranarray(np.ones((4, 3)))
    assert se2.pose_batch(t).flags.c_contiguous and np.array_equal(se2.pose_batch(t), t)
    assert se2.pose_batch([0.0, 1.0, 0.5], single=True).tolist() == [[0.0, 1.0, 0.5]]
    with pytest.raises(ValueError, match=r"poses must have shape \(N, 3\) .* got \(3,\)"):
        se2.pose_batch([0.0, 1.0, 0.5])  # one pose only where single=True says so
    with pytest.raises(ValueError, match=r"got \(2, 2\)"):
        se2.pose_batch(np.zeros((2, 2)), single=True)
    with pytest.raises(ValueError, match="poses must be finite"):
        se2.pose_batch([[0.0, np.nan, 0.0]])
