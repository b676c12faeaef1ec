"""Numba kernel of the reported pose's refinement (private; see
:func:`probmap.pipelines._localize_track.refine_pose`).

Grid convention: ``dist`` indexed ``[iy, ix]``, row 0 at the smallest y, ``(x0, y0)`` the
lower-left corner of cell ``[0, 0]``; values at the cell centres, interpolated bilinearly.
"""

from __future__ import annotations

import math

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
