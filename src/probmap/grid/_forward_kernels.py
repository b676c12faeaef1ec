"""Numba kernels for the forward sensor models (private; see :mod:`probmap.grid.forward`).

Every kernel takes contiguous arrays and scalars only; the public wrappers validate inputs.
Grid convention: arrays indexed ``[iy, ix]``, row 0 at the smallest y, ``(x0, y0)`` the
lower-left corner of cell ``[0, 0]``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def endpoints_in_robot_frame(ranges, angles, offset, max_range, lx, ly, valid):
    """Beam endpoints in the robot frame (sensor offset applied once per scan).

    ``valid[b]`` is False for max-range or non-finite readings, which the likelihood field
    skips (Probabilistic Robotics Table 6.3, line 4).
    """
    c = math.cos(offset[2])
    s = math.sin(offset[2])
    for b in range(ranges.shape[0]):
        r = ranges[b]
        ok = math.isfinite(r) and r < max_range and r >= 0.0
        valid[b] = ok
        if not ok:
            r = 0.0
        px = r * math.cos(angles[b])
        py = r * math.sin(angles[b])
        lx[b] = offset[0] + c * px - s * py
        ly[b] = offset[1] + s * px + c * py


@njit(cache=True)
def likelihood_field_per_beam(poses, lx, ly, valid, table, x0, y0, inv_res, outside, out):
    """Per-beam log-likelihoods ``out[n, b]`` by lookup in a log-likelihood table ``(H, W)``."""
    h, w = table.shape
    for n in range(poses.shape[0]):
        x = poses[n, 0]
        y = poses[n, 1]
        c = math.cos(poses[n, 2])
        s = math.sin(poses[n, 2])
        for b in range(lx.shape[0]):
            if not valid[b]:
                out[n, b] = 0.0
                continue
            ex = x + c * lx[b] - s * ly[b]
            ey = y + s * lx[b] + c * ly[b]
            fx = (ex - x0) * inv_res
            fy = (ey - y0) * inv_res
            if fx >= 0.0 and fy >= 0.0 and fx < w and fy < h:
                out[n, b] = table[int(fy), int(fx)]
            else:
                out[n, b] = outside


@njit(cache=True)
def likelihood_field_sum(poses, lx, ly, valid, table, x0, y0, inv_res, outside, out):
    """Sum over beams of the per-beam log-likelihoods: ``out[n]`` (one particle per row)."""
    h, w = table.shape
    nb = 0
    for b in range(lx.shape[0]):
        if valid[b]:
            nb += 1
    bx = np.empty(nb)
    by = np.empty(nb)
    k = 0
    for b in range(lx.shape[0]):
        if valid[b]:
            bx[k] = lx[b]
            by[k] = ly[b]
            k += 1
    for n in range(poses.shape[0]):
        x = poses[n, 0]
        y = poses[n, 1]
        c = math.cos(poses[n, 2])
        s = math.sin(poses[n, 2])
        acc = 0.0
        for b in range(nb):
            fx = (x + c * bx[b] - s * by[b] - x0) * inv_res
            fy = (y + s * bx[b] + c * by[b] - y0) * inv_res
            if fx >= 0.0 and fy >= 0.0 and fx < w and fy < h:
                acc += table[int(fy), int(fx)]
            else:
                acc += outside
        out[n] = acc


@njit(cache=True)
def cast_ray(dist, occupied, x0, y0, res, sx, sy, dx, dy, max_range):
    """Range (m) from ``(sx, sy)`` along unit direction ``(dx, dy)`` to the first occupied cell.

    Sphere tracing on the Euclidean distance transform: ``dist[iy, ix]`` is the distance (m)
    from the centre of cell ``[iy, ix]`` to the nearest occupied cell centre, so no occupied
    cell boundary lies closer than ``dist - sqrt(2) * res`` to any point of the cell. The ray
    advances by that clearance, and by half a cell where the clearance is smaller, until the
    point lands in an occupied cell (range = distance travelled), leaves the map or passes
    ``max_range`` (range = ``max_range``).
    """
    h, w = dist.shape
    inv = 1.0 / res
    margin = math.sqrt(2.0) * res
    half = 0.5 * res
    t = 0.0
    while t < max_range:
        fx = (sx + t * dx - x0) * inv
        fy = (sy + t * dy - y0) * inv
        if fx < 0.0 or fy < 0.0 or fx >= w or fy >= h:
            return max_range
        ix = int(fx)
        iy = int(fy)
        if occupied[iy, ix]:
            return t
        step = dist[iy, ix] - margin
        if step < half:
            step = half
        t += step
    return max_range


@njit(cache=True)
def cast_rays(poses, angles, offset, dist, occupied, x0, y0, res, max_range, out):
    """Expected ranges ``out[n, b]`` for every pose and beam (sensor offset applied)."""
    co = math.cos(offset[2])
    so = math.sin(offset[2])
    for n in range(poses.shape[0]):
        c = math.cos(poses[n, 2])
        s = math.sin(poses[n, 2])
        sx = poses[n, 0] + c * offset[0] - s * offset[1]
        sy = poses[n, 1] + s * offset[0] + c * offset[1]
        th = math.atan2(s * co + c * so, c * co - s * so)
        for b in range(angles.shape[0]):
            a = th + angles[b]
            out[n, b] = cast_ray(
                dist, occupied, x0, y0, res, sx, sy, math.cos(a), math.sin(a), max_range
            )


@njit(cache=True)
def beam_log_likelihood(z, zs, max_range, z_hit, z_short, z_max, z_rand, sigma, lam):
    """Log of the beam model mixture, Table 6.1, for one reading ``z`` and expectation ``zs``."""
    p = 0.0
    if z >= max_range:
        p += z_max
    else:
        if z >= 0.0:
            # Gaussian truncated to [0, max_range], normalised (equation 6.4).
            norm = 0.5 * (
                math.erf((max_range - zs) / (sigma * math.sqrt(2.0)))
                - math.erf((0.0 - zs) / (sigma * math.sqrt(2.0)))
            )
            if norm > 1e-300:
                d = z - zs
                p += (
                    z_hit
                    * math.exp(-0.5 * d * d / (sigma * sigma))
                    / (sigma * math.sqrt(2.0 * math.pi) * norm)
                )
            if z <= zs and zs > 0.0:
                p += z_short * lam * math.exp(-lam * z) / (1.0 - math.exp(-lam * zs))
            p += z_rand / max_range
    if p <= 0.0:
        return -math.inf
    return math.log(p)


@njit(cache=True)
def beam_model_per_beam(
    poses, ranges, angles, offset, dist, occupied, x0, y0, res, max_range, params, out
):
    """Per-beam log-likelihoods of the beam model with ray casting."""
    co = math.cos(offset[2])
    so = math.sin(offset[2])
    z_hit, z_short, z_max, z_rand, sigma, lam = (
        params[0],
        params[1],
        params[2],
        params[3],
        params[4],
        params[5],
    )
    for n in range(poses.shape[0]):
        c = math.cos(poses[n, 2])
        s = math.sin(poses[n, 2])
        sx = poses[n, 0] + c * offset[0] - s * offset[1]
        sy = poses[n, 1] + s * offset[0] + c * offset[1]
        th = math.atan2(s * co + c * so, c * co - s * so)
        for b in range(angles.shape[0]):
            z = ranges[b]
            if not math.isfinite(z):
                out[n, b] = 0.0
                continue
            a = th + angles[b]
            zs = cast_ray(dist, occupied, x0, y0, res, sx, sy, math.cos(a), math.sin(a), max_range)
            out[n, b] = beam_log_likelihood(
                min(z, max_range), zs, max_range, z_hit, z_short, z_max, z_rand, sigma, lam
            )
