"""Numba kernels for the forward sensor models (private; see :mod:`probmap.grid.forward`).

Every kernel takes contiguous arrays and scalars only; the public wrappers validate inputs.
The likelihood-field lookups use ``fastmath`` (they only add table entries and test bounds on
finite coordinates; no NaN or infinity reaches them), which lets LLVM reorder the sums.
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


@njit(cache=True, fastmath=True)
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


@njit(cache=True, fastmath=True)
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


@njit(cache=True, fastmath=True)
def cast_fan(dist, x0, y0, res, sx, sy, dirx, diry, max_range, t, live, out):
    """Cast a fan of rays from ``(sx, sy)`` along unit directions ``(dirx, diry)``.

    ``out[b]`` receives the range (m) to the first occupied cell along ray ``b``. Method:
    sphere tracing on the Euclidean distance transform. ``dist[iy, ix]`` is the distance (m)
    from the centre of cell ``[iy, ix]`` to the nearest occupied cell centre (0 exactly in
    occupied cells), so no occupied cell boundary lies closer than ``dist - sqrt(2) * res`` to
    any point of the cell. A ray advances by that clearance, and by half a cell where the
    clearance is smaller, until its point lands in an occupied cell (range = distance
    travelled), leaves the map or reaches ``max_range`` (range = ``max_range``).

    All unfinished rays advance one step at a time: their dependency chains (position ->
    table lookup -> next position) are independent, so the processor overlaps their memory
    latencies (2x faster than tracing one ray after the other). ``t`` (float) and ``live``
    (int) are scratch arrays of the fan's length.
    """
    h, w = dist.shape
    inv = 1.0 / res
    margin = math.sqrt(2.0) * res
    half = 0.5 * res
    m = dirx.shape[0]
    for b in range(m):
        t[b] = 0.0
        live[b] = b
    while m > 0:
        k = 0
        for j in range(m):
            b = live[j]
            tb = t[b]
            fx = (sx + tb * dirx[b] - x0) * inv
            fy = (sy + tb * diry[b] - y0) * inv
            if tb >= max_range or fx < 0.0 or fy < 0.0 or fx >= w or fy >= h:
                out[b] = max_range
                continue
            d = dist[int(fy), int(fx)]
            if d <= 0.0:
                out[b] = tb
                continue
            step = d - margin
            if step < half:
                step = half
            t[b] = tb + step
            live[k] = b
            k += 1
        m = k


@njit(cache=True)
def cast_rays(poses, angles, offset, dist, x0, y0, res, max_range, out):
    """Expected ranges ``out[n, b]`` for every pose and beam (sensor offset applied).

    Beam directions are rotated from per-beam cosines and sines computed once.
    """
    nb = angles.shape[0]
    cb = np.empty(nb)
    sb = np.empty(nb)
    for b in range(nb):
        cb[b] = math.cos(angles[b] + offset[2])
        sb[b] = math.sin(angles[b] + offset[2])
    dirx = np.empty(nb)
    diry = np.empty(nb)
    t = np.empty(nb)
    live = np.empty(nb, dtype=np.int64)
    for n in range(poses.shape[0]):
        c = math.cos(poses[n, 2])
        s = math.sin(poses[n, 2])
        sx = poses[n, 0] + c * offset[0] - s * offset[1]
        sy = poses[n, 1] + s * offset[0] + c * offset[1]
        for b in range(nb):
            dirx[b] = c * cb[b] - s * sb[b]
            diry[b] = s * cb[b] + c * sb[b]
        cast_fan(dist, x0, y0, res, sx, sy, dirx, diry, max_range, t, live, out[n])


@njit(cache=True)
def beam_log_likelihood(z, zs, max_range, z_hit, z_short, z_max, z_rand, sigma, lam):
    """Log of the beam model mixture, Table 6.1, for one reading ``z`` and expectation ``zs``."""
    p = 0.0
    if z >= max_range:
        p += z_max
    else:
        if z >= 0.0:
            # Gaussian truncated to [0, max_range], normalised (equation 6.4); eta differs
            # from 1 by under 1e-15 when zs is more than 8 sigma inside both ends.
            k = sigma * math.sqrt(2.0)
            if zs > 8.0 * sigma and max_range - zs > 8.0 * sigma:
                norm = 1.0
            else:
                norm = 0.5 * (math.erf((max_range - zs) / k) + math.erf(zs / k))
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
def beam_model_per_beam(poses, ranges, angles, offset, dist, x0, y0, res, max_range, params, out):
    """Per-beam log-likelihoods of the beam model with ray casting (non-finite readings: 0)."""
    z_hit, z_short, z_max, z_rand, sigma, lam = (
        params[0],
        params[1],
        params[2],
        params[3],
        params[4],
        params[5],
    )
    nb = angles.shape[0]
    cb = np.empty(nb)
    sb = np.empty(nb)
    ok = np.empty(nb, dtype=np.bool_)
    for b in range(nb):
        cb[b] = math.cos(angles[b] + offset[2])
        sb[b] = math.sin(angles[b] + offset[2])
        ok[b] = math.isfinite(ranges[b])
    dirx = np.empty(nb)
    diry = np.empty(nb)
    t = np.empty(nb)
    live = np.empty(nb, dtype=np.int64)
    zs = np.empty(nb)
    for n in range(poses.shape[0]):
        c = math.cos(poses[n, 2])
        s = math.sin(poses[n, 2])
        sx = poses[n, 0] + c * offset[0] - s * offset[1]
        sy = poses[n, 1] + s * offset[0] + c * offset[1]
        for b in range(nb):
            dirx[b] = c * cb[b] - s * sb[b]
            diry[b] = s * cb[b] + c * sb[b]
        cast_fan(dist, x0, y0, res, sx, sy, dirx, diry, max_range, t, live, zs)
        for b in range(nb):
            if not ok[b]:
                out[n, b] = 0.0
                continue
            out[n, b] = beam_log_likelihood(
                min(ranges[b], max_range),
                zs[b],
                max_range,
                z_hit,
                z_short,
                z_max,
                z_rand,
                sigma,
                lam,
            )
