"""Numba kernels of the beam model (private; see :mod:`probmap.models.beam`).

The one log-likelihood of the beam model, ``log p(z | z*)`` of one reading (Probabilistic
Robotics eq. 6.12, Table 6.1, :func:`beam_log_likelihood`), and the kernels built on it: over
flat arrays (:func:`beam_log_likelihoods`, for
:meth:`probmap.models.beam.BeamModelParams.log_likelihood`), over poses and beams given expected
ranges (:func:`beam_mixture`) and with expected ranges from a lookup table
(:func:`table_beam_model`, whose ``z*``-only factors :func:`table_normalisers` computes with the
same arithmetic). The MAP mapper's kernels (:mod:`probmap.mapping._map_kernels`) call
:func:`beam_log_likelihood_of` for every cell of every beam's window.

Expected ranges ``z*`` come from one of three casters: sphere tracing on a distance transform
(:func:`cast_rays`), exact grid traversal (:func:`exact_ranges`, with
:func:`probmap.grid._traverse.cast_exact`, the grid's one traversal kernel) and a lookup table of
exact casts (:func:`table_ranges`).

Every kernel takes contiguous arrays and scalars only and trusts its inputs; the public classes
validate once. Grid convention: arrays indexed ``[iy, ix]``, row 0 at the smallest y, ``(x0, y0)``
the lower-left corner of cell ``[0, 0]``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from probmap.grid._traverse import cast_exact


@njit(cache=True)
def beam_log_likelihood(z, zs, max_range, z_hit, z_short, z_max, z_rand, sigma, lam):
    """``log p(z | z*)`` of the beam model mixture (Probabilistic Robotics eq. 6.12, Table 6.1).

    The hit Gaussian is truncated to ``[0, max_range]`` and normalised (eq. 6.4), the short
    exponential to ``[0, z*]`` (eq. 6.7); ``z >= max_range`` is the max-range point mass alone,
    and a negative reading has density 0 (``-inf``), as has any reading when every weight that
    could explain it is 0.
    """
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


@njit(cache=True, inline="always")
def beam_log_likelihood_of(z, zs, max_range, params):
    """:func:`beam_log_likelihood` with the intrinsic parameters in one array ``params``,
    ``[z_hit, z_short, z_max, z_rand, sigma_hit, lambda_short]``
    (:meth:`probmap.models.beam.BeamModelParams.as_array`)."""
    return beam_log_likelihood(
        z, zs, max_range, params[0], params[1], params[2], params[3], params[4], params[5]
    )


@njit(cache=True)
def beam_log_likelihoods(z, zs, max_range, params, out):
    """:func:`beam_log_likelihood_of` over flat arrays ``z``, ``zs`` into ``out``."""
    for i in range(z.shape[0]):
        out[i] = beam_log_likelihood_of(z[i], zs[i], max_range, params)


@njit(cache=True)
def beam_mixture(zs, ranges, max_range, params, out):
    """Per-beam log-likelihoods ``out[n, b]`` of readings ``ranges[b]`` given expected ranges
    ``zs[n, b]`` (Table 6.1; readings clipped to ``max_range``; non-finite readings: 0)."""
    nb = ranges.shape[0]
    for n in range(zs.shape[0]):
        for b in range(nb):
            r = ranges[b]
            if not math.isfinite(r):
                out[n, b] = 0.0
                continue
            out[n, b] = beam_log_likelihood_of(min(r, max_range), zs[n, b], max_range, params)


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


@njit(cache=True, inline="always")
def sensor_in_grid(poses, n, offset, x0, y0, inv):
    """Position of the sensor of pose ``poses[n]`` (robot frame offset ``offset``) in grid
    units: cells from the lower-left corner ``(x0, y0)``, ``inv`` cells per metre."""
    c = math.cos(poses[n, 2])
    s = math.sin(poses[n, 2])
    return (
        (poses[n, 0] + c * offset[0] - s * offset[1] - x0) * inv,
        (poses[n, 1] + s * offset[0] + c * offset[1] - y0) * inv,
    )


@njit(cache=True)
def exact_ranges(poses, angles, offset, occ, x0, y0, res, max_range, out):
    """Expected ranges ``out[n, b]`` (m) by exact traversal from the sensor position."""
    inv = 1.0 / res
    limit = max_range * inv
    for n in range(poses.shape[0]):
        gx, gy = sensor_in_grid(poses, n, offset, x0, y0, inv)
        for b in range(angles.shape[0]):
            a = poses[n, 2] + offset[2] + angles[b]
            t = cast_exact(occ, gx, gy, math.cos(a), math.sin(a), limit)
            out[n, b] = min(t * res, max_range)


@njit(cache=True)
def fill_entry(occ, table, ix, iy, k, width, res, max_range, quantum):
    """Cast ``table[iy, ix, k]`` exactly from the cell centre at heading ``k * width``, store
    ``1 + round(range / quantum)`` and return it (kept out of line: the lookups stay tight)."""
    a = k * width
    t = cast_exact(occ, ix + 0.5, iy + 0.5, math.cos(a), math.sin(a), max_range / res)
    v = np.uint16(int(min(t * res, max_range) / quantum + 0.5) + 1)
    table[iy, ix, k] = v
    return v


@njit(cache=True, inline="always")
def heading_bin(angle, inv_width, nk):
    """Index in ``[0, nk)`` of the heading bin nearest to ``angle`` (rad)."""
    k = int(math.floor(angle * inv_width + 0.5))
    if k < 0 or k >= nk:
        k = k % nk  # Python semantics: in [0, nk) for negative k too
    return k


@njit(cache=True)
def table_ranges(poses, angles, offset, occ, table, x0, y0, res, max_range, quantum, out):
    """Expected ranges ``out[n, b]`` (m) from a ray-casting lookup table, filled on first use.

    ``table[iy, ix, k]`` (uint16) holds ``1 + round(r / quantum)`` where ``r`` is the exact
    range (:func:`cast_exact`) from the centre of cell ``[iy, ix]`` at heading
    ``k * 2 pi / K``; 0 marks an entry not computed yet, which is cast and stored when first
    asked for. A query takes the cell of the sensor position and the nearest heading bin. A
    sensor outside the map reads ``max_range`` (as a ray that leaves the map does).
    """
    h, w, nk = table.shape
    width = 2.0 * math.pi / nk
    inv_width = nk / (2.0 * math.pi)
    inv = 1.0 / res
    nb = angles.shape[0]
    for n in range(poses.shape[0]):
        fx, fy = sensor_in_grid(poses, n, offset, x0, y0, inv)
        if not (fx >= 0.0 and fy >= 0.0 and fx < w and fy < h):
            for b in range(nb):
                out[n, b] = max_range
            continue
        ix = int(fx)
        iy = int(fy)
        heading = poses[n, 2] + offset[2]
        for b in range(nb):
            k = heading_bin(heading + angles[b], inv_width, nk)
            v = table[iy, ix, k]
            if v == 0:
                v = fill_entry(occ, table, ix, iy, k, width, res, max_range, quantum)
            out[n, b] = (v - 1) * quantum


@njit(cache=True)
def table_normalisers(quantum, max_range, params, scales):
    """Per table value ``v`` (expected range ``zs = (v - 1) * quantum``) the factors of Table 6.1
    that depend on ``zs`` alone, side by side (one cache line per lookup):
    ``scales[v, 0] = z_hit / (sqrt(2 pi) sigma eta(zs))`` (0 where ``eta`` underflows) and
    ``scales[v, 1] = z_short lambda / (1 - exp(-lambda zs))`` (0 at ``zs = 0``); the same
    arithmetic as :func:`beam_log_likelihood`."""
    z_hit, z_short, sigma, lam = params[0], params[1], params[4], params[5]
    k = sigma * math.sqrt(2.0)
    scales[0, 0] = 0.0
    scales[0, 1] = 0.0
    for v in range(1, scales.shape[0]):
        zs = (v - 1) * quantum
        if zs > 8.0 * sigma and max_range - zs > 8.0 * sigma:
            norm = 1.0
        else:
            norm = 0.5 * (math.erf((max_range - zs) / k) + math.erf(zs / k))
        scales[v, 0] = z_hit / (sigma * math.sqrt(2.0 * math.pi) * norm) if norm > 1e-300 else 0.0
        scales[v, 1] = z_short * lam / (1.0 - math.exp(-lam * zs)) if zs > 0.0 else 0.0


@njit(cache=True)
def table_beam_model(
    poses,
    ranges,
    angles,
    offset,
    occ,
    table,
    scales,
    x0,
    y0,
    res,
    max_range,
    quantum,
    params,
    out,
):
    """Per-beam log-likelihoods of the beam model (Table 6.1) with expected ranges from the
    lookup table (see :func:`table_ranges`) and the ``zs``-only factors from
    :func:`table_normalisers`: one exponential and one logarithm per particle and beam."""
    z_max, z_rand, sigma, lam = params[2], params[3], params[4], params[5]
    h, w, nk = table.shape
    width = 2.0 * math.pi / nk
    inv = 1.0 / res
    nb = angles.shape[0]
    # per-beam constants: clipped reading, exp(-lambda z), the constant terms
    zc = np.empty(nb)
    decay = np.empty(nb)
    kind = np.empty(nb, dtype=np.int64)  # 0 ordinary, 1 max range, 2 non-finite
    log_max = math.log(z_max) if z_max > 0.0 else -math.inf
    for b in range(nb):
        r = ranges[b]
        kind[b] = 2 if not math.isfinite(r) else (1 if r >= max_range else 0)
        zc[b] = min(r, max_range) if kind[b] != 2 else 0.0
        decay[b] = math.exp(-lam * zc[b])
    floor = z_rand / max_range
    inv2s2 = 0.5 / (sigma * sigma)
    zs_of = np.empty(nb, dtype=np.int64)
    outside = int(max_range / quantum + 0.5) + 1
    inv_width = nk / (2.0 * math.pi)
    for n in range(poses.shape[0]):
        fx, fy = sensor_in_grid(poses, n, offset, x0, y0, inv)
        inside = fx >= 0.0 and fy >= 0.0 and fx < w and fy < h
        heading = poses[n, 2] + offset[2]
        ix = int(fx) if inside else 0
        iy = int(fy) if inside else 0
        for b in range(nb):
            if inside:
                k = heading_bin(heading + angles[b], inv_width, nk)
                v = table[iy, ix, k]
                if v == 0:
                    v = fill_entry(occ, table, ix, iy, k, width, res, max_range, quantum)
                zs_of[b] = v
            else:
                zs_of[b] = outside
        for b in range(nb):
            if kind[b] == 2:
                out[n, b] = 0.0
                continue
            if kind[b] == 1:
                out[n, b] = log_max
                continue
            v = zs_of[b]
            zs = (v - 1) * quantum
            d = zc[b] - zs
            p = scales[v, 0] * math.exp(-inv2s2 * d * d) + floor
            if zc[b] <= zs:
                p += scales[v, 1] * decay[b]
            out[n, b] = math.log(p) if p > 0.0 else -math.inf
