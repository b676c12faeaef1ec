"""Numba primitives shared by the landmark SLAM kernels (private).

:mod:`probmap.slam.landmark.graphslam._kernels` and :mod:`probmap.slam.landmark._fastslam_kernels` both
predict range-bearing measurements with their Jacobians and multiply small dense blocks inside
compiled loops; this module is the one home of those pieces (the angle wrap they share with the
pose-graph kernels is :func:`probmap.geometry._kernels.wrap`). Inputs are plain float64
arrays and scalars, validated by the public functions that call the kernels.
"""

from __future__ import annotations

import math

from numba import njit

from probmap.geometry._kernels import wrap


@njit(cache=True)
def range_bearing(px, py, pth, offset, mx, my, hm, hx):  # pragma: no cover - compiled
    """Range-bearing ``h`` of landmark ``(mx, my)`` (m) from pose ``(px, py, pth)`` (m, m, rad)
    with the sensor at ``offset = (dx, dy, dth)`` in the robot frame (as
    ``RangeBearingModel.predict``).

    Returns ``(r, phi)`` (m, rad, bearing wrapped) and fills ``hm (2, 2) = dh / dm`` and
    ``hx (2, 3) = dh / dx``. A landmark on the sensor has no bearing: its squared range is
    clamped to ``1e-18`` (``r = 1e-9``) so that the outputs stay finite; a caller that must
    reject it tests ``r <= ZERO_RANGE``.
    """
    c = math.cos(pth)
    s = math.sin(pth)
    sx = px + c * offset[0] - s * offset[1]
    sy = py + s * offset[0] + c * offset[1]
    dsx = -s * offset[0] - c * offset[1]
    dsy = c * offset[0] - s * offset[1]
    dx = mx - sx
    dy = my - sy
    q = max(dx * dx + dy * dy, 1e-18)
    r = math.sqrt(q)
    hm[0, 0] = dx / r
    hm[0, 1] = dy / r
    hm[1, 0] = -dy / q
    hm[1, 1] = dx / q
    for i in range(2):
        hx[i, 0] = -hm[i, 0]
        hx[i, 1] = -hm[i, 1]
        hx[i, 2] = -(hm[i, 0] * dsx + hm[i, 1] * dsy)
    hx[1, 2] -= 1.0
    return r, wrap(math.atan2(dy, dx) - (pth + offset[2]))


ZERO_RANGE = math.sqrt(1e-18)
"""The range :func:`range_bearing` reports for a landmark on the sensor (m)."""


@njit(cache=True)
def gemm(A, B, alpha, out):  # pragma: no cover - compiled
    """``out += alpha A B`` for small dense blocks (pass ``X.T`` for a transpose).

    Each entry is accumulated onto ``out`` in order (``acc = out[i, j]``, then
    ``acc += alpha A[i, k] B[k, j]`` for ``k = 0, 1, ...``), so ``alpha = +-1`` rounds exactly
    as the written-out loop ``acc = base; acc +-= A[i, k] B[k, j]`` does.
    """
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            acc = out[i, j]
            for k in range(A.shape[1]):
                acc += alpha * A[i, k] * B[k, j]
            out[i, j] = acc
