"""Numba kernels of the likelihood field model (private; see :mod:`probmap.models.likelihood_field`).

Every kernel takes contiguous arrays and scalars only; the public class validates inputs. The
lookups use ``fastmath`` (they only add table entries and test bounds on finite coordinates; no
NaN or infinity reaches them), which lets LLVM reorder the sums. Grid convention: arrays indexed
``[iy, ix]``, row 0 at the smallest y, ``(x0, y0)`` the lower-left corner of cell ``[0, 0]``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from probmap.grid._traverse import cast_exact


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


@njit(cache=True, fastmath=True, inline="always")
def scan_log_likelihood(x, y, c, s, lx, ly, table, x0, y0, inv_res, outside):
    """Sum of the table's log-likelihoods at the endpoints ``lx, ly`` (B,) (robot frame) seen
    from the pose ``(x, y)`` with heading cosine and sine ``c, s``; ``outside`` for each endpoint
    off the table (Table 6.3, lines 3-8, summed in log space).

    The one lookup loop of the likelihood field: :func:`likelihood_field_sum` and MCL's fused
    step (:func:`probmap.filters._kernels.odometry_predict_and_weight`) inline it.
    """
    h, w = table.shape
    acc = 0.0
    for b in range(lx.shape[0]):
        fx = (x + c * lx[b] - s * ly[b] - x0) * inv_res
        fy = (y + s * lx[b] + c * ly[b] - y0) * inv_res
        if fx >= 0.0 and fy >= 0.0 and fx < w and fy < h:
            acc += table[int(fy), int(fx)]
        else:
            acc += outside
    return acc


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
        c = math.cos(poses[n, 2])
        s = math.sin(poses[n, 2])
        out[n] = scan_log_likelihood(
            poses[n, 0], poses[n, 1], c, s, bx, by, table, x0, y0, inv_res, outside
        )


@njit(cache=True)
def wall_row(slots, pool, cells, state, bx, by):
    """The row of ``pool`` (P, K) that caches the wall ranges cast from block ``[by, bx]`` of
    ``slots`` (-1: none yet), assigned on first use; a full pool is wiped (every block
    forgotten) and filled again. ``cells`` (P,) remembers each row's block, ``state[0]`` the
    rows in use (``state[1]``: how far casts go, cells)."""
    r = slots[by, bx]
    if r >= 0:
        return r
    n = state[0]
    w = slots.shape[1]
    if n == pool.shape[0]:
        for i in range(n):
            slots[cells[i] // w, cells[i] % w] = -1
        pool[:, :] = 0
        n = 0
    slots[by, bx] = n
    cells[n] = by * w + bx
    state[0] = n + 1
    return n


@njit(cache=True)
def cast_wall(occ, pool, row, k, gx, gy, width, limit, quantum):
    """Cast from grid point ``(gx, gy)`` (cells) at heading ``k * width`` to the first occupied
    cell of ``occ`` (at most ``limit`` cells), store ``1 + round(range / quantum)`` (range in
    cells) in ``pool[row, k]`` and return it (kept out of line: the lookups stay tight)."""
    a = k * width
    t = cast_exact(occ, gx, gy, math.cos(a), math.sin(a), limit)
    v = np.uint16(min(int(t / quantum + 0.5), 65534) + 1)
    pool[row, k] = v
    return v


@njit(cache=True, fastmath=True, inline="always")
def scan_log_likelihood_walls(
    x, y, th, lx, ly, table, x0, y0, inv_res, outside,
    ox, oy, beam_angle, beam_range, margin, occ, slots, pool, cells, state, block, quantum,
):  # fmt: skip
    """:func:`scan_log_likelihood` where a beam that runs through a wall of the map counts as a
    random reading: its endpoint scores ``outside`` (the field's floor) when the first occupied
    cell along it lies more than ``margin`` short of its range (all in cells).

    ``ox, oy`` is the laser's position in the robot frame (m), ``beam_angle`` (B,) each beam's
    direction in the robot frame (rad) and ``beam_range`` (B,) its length from the laser
    (cells). The first wall's range comes from a cache of exact casts (``pool``, ``K`` heading
    bins per row) from the centre of the laser's block of ``block x block`` cells, filled on
    first use; only a beam whose endpoint scores above the floor is looked up.
    """
    h, w = table.shape
    nk = pool.shape[1]
    width = 2.0 * math.pi / nk
    inv_width = nk / (2.0 * math.pi)
    c = math.cos(th)
    s = math.sin(th)
    fx = (x + c * ox - s * oy - x0) * inv_res
    fy = (y + s * ox + c * oy - y0) * inv_res
    row = -1
    gx = 0.0
    gy = 0.0
    if fx >= 0.0 and fy >= 0.0 and fx < w and fy < h:
        bx = int(fx) // block
        by = int(fy) // block
        row = wall_row(slots, pool, cells, state, bx, by)
        gx = min((bx + 0.5) * block, w - 0.5)
        gy = min((by + 0.5) * block, h - 0.5)
    limit = float(state[1])
    acc = 0.0
    for b in range(lx.shape[0]):
        ex = (x + c * lx[b] - s * ly[b] - x0) * inv_res
        ey = (y + s * lx[b] + c * ly[b] - y0) * inv_res
        if ex >= 0.0 and ey >= 0.0 and ex < w and ey < h:
            v = table[int(ey), int(ex)]
        else:
            v = outside
        if v > outside and row >= 0 and beam_range[b] > margin:
            a = th + beam_angle[b]
            k = int(math.floor(a * inv_width + 0.5)) % nk
            e = pool[row, k]
            if e == 0:
                e = cast_wall(occ, pool, row, k, gx, gy, width, limit, quantum)
            if (e - 1) * quantum + margin < beam_range[b]:
                v = outside
        acc += v
    return acc


@njit(cache=True)
def likelihood_field_sum_walls(
    poses, lx, ly, table, x0, y0, inv_res, outside,
    ox, oy, beam_angle, beam_range, margin, occ, slots, pool, cells, state, block, quantum, out,
):  # fmt: skip
    """:func:`scan_log_likelihood_walls` for every pose: ``out[n]`` (valid beams only)."""
    for n in range(poses.shape[0]):
        out[n] = scan_log_likelihood_walls(
            poses[n, 0], poses[n, 1], poses[n, 2], lx, ly, table, x0, y0, inv_res, outside,
            ox, oy, beam_angle, beam_range, margin, occ, slots, pool, cells, state, block,
            quantum,
        )  # fmt: skip
