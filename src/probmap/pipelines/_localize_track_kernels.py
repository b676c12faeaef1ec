"""Numba kernel of the reported pose's refinement (private; see
:func:`probmap.pipelines._localize_track.refine_pose`).

Grid convention: ``dist`` indexed ``[iy, ix]``, row 0 at the smallest y, ``(x0, y0)`` the
lower-left corner of cell ``[0, 0]``; values at the cell centres, interpolated bilinearly.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def scan_terms(dist, x0, y0, res, far, outlier, bx, by, x, y, th, g, H):  # pragma: no cover
    """Gauss-Newton terms of the scan ``(bx, by)`` (robot frame) seen from ``(x, y, th)``.

    Each endpoint's residual is its distance to the nearest obstacle (bilinear; ``far`` off
    the grid); those within ``outlier`` add ``J^T d`` to ``g`` (3,) and ``J^T J`` to ``H``
    (3, 3), both zeroed first. Returns ``(sum of min(d, outlier)^2, inliers)``.
    """
    for a in range(3):
        g[a] = 0.0
        for b in range(3):
            H[a, b] = 0.0
    h, w = dist.shape
    c = math.cos(th)
    s = math.sin(th)
    cost = 0.0
    inliers = 0
    for i in range(bx.shape[0]):
        rx = c * bx[i] - s * by[i]
        ry = s * bx[i] + c * by[i]
        fx = (x + rx - x0) / res - 0.5
        fy = (y + ry - y0) / res - 0.5
        ix = int(math.floor(fx))
        iy = int(math.floor(fy))
        if ix < 0 or iy < 0 or ix >= w - 1 or iy >= h - 1:
            d = far
            gx = 0.0
            gy = 0.0
        else:
            tx = fx - ix
            ty = fy - iy
            d00 = dist[iy, ix]
            d10 = dist[iy, ix + 1]
            d01 = dist[iy + 1, ix]
            d11 = dist[iy + 1, ix + 1]
            d = (d00 * (1 - tx) + d10 * tx) * (1 - ty) + (d01 * (1 - tx) + d11 * tx) * ty
            gx = ((d10 - d00) * (1 - ty) + (d11 - d01) * ty) / res
            gy = ((d01 - d00) * (1 - tx) + (d11 - d10) * tx) / res
        if d <= outlier:
            inliers += 1
            cost += d * d
            j0 = gx
            j1 = gy
            j2 = -gx * ry + gy * rx
            g[0] += j0 * d
            g[1] += j1 * d
            g[2] += j2 * d
            H[0, 0] += j0 * j0
            H[0, 1] += j0 * j1
            H[0, 2] += j0 * j2
            H[1, 1] += j1 * j1
            H[1, 2] += j1 * j2
            H[2, 2] += j2 * j2
        else:
            cost += outlier * outlier
    H[1, 0] = H[0, 1]
    H[2, 0] = H[0, 2]
    H[2, 1] = H[1, 2]
    return cost, inliers


@njit(cache=True)
def _wrap(a):  # pragma: no cover
    """``a`` wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True)
def _solve3(A, b, out):  # pragma: no cover
    """``out = A^-1 b`` for a symmetric positive definite (3, 3) ``A`` by Cholesky; False when
    ``A`` is not."""
    l00 = A[0, 0]
    if not l00 > 0.0:
        return False
    l00 = math.sqrt(l00)
    l10 = A[1, 0] / l00
    l20 = A[2, 0] / l00
    d = A[1, 1] - l10 * l10
    if not d > 0.0:
        return False
    l11 = math.sqrt(d)
    l21 = (A[2, 1] - l20 * l10) / l11
    d = A[2, 2] - l20 * l20 - l21 * l21
    if not d > 0.0:
        return False
    l22 = math.sqrt(d)
    y0 = b[0] / l00
    y1 = (b[1] - l10 * y0) / l11
    y2 = (b[2] - l20 * y0 - l21 * y1) / l22
    out[2] = y2 / l22
    out[1] = (y1 - l21 * out[2]) / l11
    out[0] = (y0 - l10 * out[1] - l20 * out[2]) / l00
    return True


@njit(cache=True)
def _prior_terms(x, mu, prior, dx, pg):  # pragma: no cover
    """``dx = x - mu`` (heading wrapped), ``pg = prior dx``; returns ``dx^T prior dx``."""
    for a in range(3):
        dx[a] = x[a] - mu[a]
    dx[2] = _wrap(dx[2])
    q = 0.0
    for a in range(3):
        pg[a] = prior[a, 0] * dx[0] + prior[a, 1] * dx[1] + prior[a, 2] * dx[2]
        q += dx[a] * pg[a]
    return q


@njit(cache=True)
def refine(
    dist, x0, y0, res, far, outlier, s2, bx, by, mu, prior, iterations, x
):  # pragma: no cover
    """Gauss-Newton on ``sum min(d, outlier)^2 / s2 + (x - mu)^T prior (x - mu)`` from ``mu``
    (see :func:`probmap.pipelines._localize_track.refine_pose`); steps of at most one cell and
    2 deg, kept only when they lower the cost. Writes the pose into ``x`` (3,); returns the
    inliers there and its squared Mahalanobis distance ``dx^T prior dx``."""
    g = np.empty(3)
    H = np.empty((3, 3))
    A = np.empty((3, 3))
    rhs = np.empty(3)
    step = np.empty(3)
    dx = np.empty(3)
    pg = np.empty(3)
    cand = np.empty(3)
    max_turn = math.radians(2.0)
    for a in range(3):
        x[a] = mu[a]
    sq, n_in = scan_terms(dist, x0, y0, res, far, outlier, bx, by, x[0], x[1], x[2], g, H)
    q = _prior_terms(x, mu, prior, dx, pg)
    cost = sq / s2 + q
    for _ in range(iterations):
        for a in range(3):
            for b in range(3):
                A[a, b] = H[a, b] / s2 + prior[a, b]
            rhs[a] = -(g[a] / s2 + pg[a])
        if not _solve3(A, rhs, step):
            break
        shrink = max(math.hypot(step[0], step[1]) / res, abs(step[2]) / max_turn)
        if shrink > 1.0:
            for a in range(3):
                step[a] /= shrink
        for a in range(3):
            cand[a] = x[a] + step[a]
        c_sq, c_in = scan_terms(
            dist, x0, y0, res, far, outlier, bx, by, cand[0], cand[1], cand[2], g, H
        )
        c_q = _prior_terms(cand, mu, prior, dx, pg)
        c_cost = c_sq / s2 + c_q
        if not c_cost < cost:
            _prior_terms(x, mu, prior, dx, pg)
            scan_terms(dist, x0, y0, res, far, outlier, bx, by, x[0], x[1], x[2], g, H)
            break
        for a in range(3):
            x[a] = cand[a]
        cost, n_in, q = c_cost, c_in, c_q
        if math.hypot(step[0], step[1]) < 1e-4 and abs(step[2]) < 1e-4:
            break
    x[2] = _wrap(x[2])
    return n_in, q
