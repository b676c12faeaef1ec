"""The compiled primitives shared by the GraphSLAM and FastSLAM kernels against plain numpy:
the block product ``gemm`` (with transposed views, and rounding exactly as the written-out loop
it replaced) and the range-bearing model's zero-range flag. ``range_bearing`` against the model
itself is in ``test_fastslam_kernels.py``."""

from __future__ import annotations

import numpy as np

from probmap.geometry._kernels import wrap
from probmap.geometry.se2 import wrap_angle
from probmap.slam.landmark._kernels import ZERO_RANGE, gemm, range_bearing


def _loop(base, A, B, sign):
    """The loop ``gemm`` replaced: ``acc = base[i, j]; acc +-= A[i, k] B[k, j]``."""
    out = base.copy()
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            acc = out[i, j]
            for k in range(A.shape[1]):
                acc = acc + A[i, k] * B[k, j] if sign > 0 else acc - A[i, k] * B[k, j]
            out[i, j] = acc
    return out


def test_gemm_equals_numpy_and_the_loop_bit_for_bit():
    rng = np.random.default_rng(0)
    for shape in [(3, 3, 3), (3, 6, 6), (3, 2, 3), (2, 3, 2)]:
        n, k, m = shape
        A, Bt, base = rng.normal(size=(n, k)), rng.normal(size=(m, k)), rng.normal(size=(n, m))
        for alpha in (1.0, -1.0):
            out = base.copy()
            gemm(A, Bt.T, alpha, out)  # a transposed view, as the kernels pass
            np.testing.assert_allclose(out, base + alpha * A @ Bt.T, rtol=1e-13, atol=1e-13)
            np.testing.assert_array_equal(out, _loop(base, A, Bt.T, alpha))


def test_gemm_into_a_column_slice():
    rng = np.random.default_rng(1)
    A, B = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    J = np.zeros((3, 6))
    J[:, :3] = 1.0
    gemm(A, B, -1.0, J[:, :3])
    np.testing.assert_allclose(J[:, :3], 1.0 - A @ B, rtol=1e-13, atol=1e-13)
    assert not J[:, 3:].any()


def test_range_bearing_flags_a_landmark_on_the_sensor_and_wrap():
    hm, hx = np.empty((2, 2)), np.empty((2, 3))
    off = np.array([0.5, 0.0, 0.0])
    r, _ = range_bearing(1.0, 2.0, 0.0, off, 1.5, 2.0, hm, hx)  # the sensor is at (1.5, 2)
    assert r == ZERO_RANGE and np.all(np.isfinite(hm)) and np.all(np.isfinite(hx))
    r, b = range_bearing(1.0, 2.0, 0.0, off, 1.5, 3.0, hm, hx)
    assert r > ZERO_RANGE and abs(r - 1.0) < 1e-15 and abs(b - np.pi / 2) < 1e-15
    for a in np.linspace(-20.0, 20.0, 81):
        assert abs(wrap(a) - float(wrap_angle(a))) < 1e-12
