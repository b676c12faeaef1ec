"""Numba kernels for MAP occupancy grid mapping (private; see :mod:`probmap.mapping.map_mapping`).

The kernels take plain contiguous arrays and scalars and trust their inputs; the public
functions validate once. Cells are numbered ``iy * W + ix`` (row 0 at the smallest y).

Data layout (two compressed sparse rows over the same "entries"):

- forward, per beam ``b``: entries ``f_ptr[b] : f_ptr[b + 1]`` hold the cells of the beam's
  window (``f_cell``), sorted by the range ``f_dist`` (m) at which the beam first meets them,
  and ``f_ll``, the beam's log-likelihood if that cell were the first occupied one;
- inverse, per cell ``c``: ``i_entry[i_ptr[c] : i_ptr[c + 1]]`` are the entries that name ``c``
  (``e_beam`` gives their beam), i.e. the beams whose likelihood depends on ``c``.

Because a beam's entries are sorted by range, its first occupied entry (the smallest index
whose cell is occupied) gives the expected range ``z*`` of the beam model.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from probmap.grid._traverse import ray_cells
from probmap.models._beam_kernels import beam_log_likelihood_of


@njit(cache=True)
def build_entries(
    sx, sy, theta, z, length, offsets, x0, y0, res, h, w, max_range, params, capacity
):
    """Forward entries of every beam: its window's cells sorted by range, with ``f_ll``.

    Parameters are per beam: sensor position ``(sx, sy)`` (m), direction ``theta`` (rad), reading
    ``z`` (m) and window length ``length`` (m); ``offsets`` (K,) are the sub-ray angles of a cone
    (``[0.0]`` for a laser). A cell's range is the smallest over the sub-rays that cross it.

    Returns ``(f_ptr, f_cell, f_dist, f_ll)``.
    """
    nb = sx.shape[0]
    k = offsets.shape[0]
    f_ptr = np.zeros(nb + 1, dtype=np.int64)
    f_cell = np.empty(capacity, dtype=np.int32)
    f_dist = np.empty(capacity, dtype=np.float64)
    f_ll = np.empty(capacity, dtype=np.float64)
    mark = np.full(h * w, -1, dtype=np.int64)
    slot = np.zeros(h * w, dtype=np.int64)
    inv = 1.0 / res
    per_ray = 0
    for b in range(nb):
        m = int(length[b] * inv * 2.0) + 4
        if m > per_ray:
            per_ray = m
    tmp_c = np.empty(per_ray * k, dtype=np.int64)
    tmp_d = np.empty(per_ray * k, dtype=np.float64)
    uc = np.empty(per_ray * k, dtype=np.int64)
    ud = np.empty(per_ray * k, dtype=np.float64)
    out = 0
    for b in range(nb):
        gx = (sx[b] - x0) * inv
        gy = (sy[b] - y0) * inv
        n = 0
        for j in range(k):
            a = theta[b] + offsets[j]
            n = ray_cells(gx, gy, math.cos(a), math.sin(a), length[b] * inv, w, h, tmp_c, tmp_d, n)
        # union of the sub-rays' cells, each at its smallest range
        u = 0
        for i in range(n):
            c = tmp_c[i]
            if mark[c] == b:
                s = slot[c]
                if tmp_d[i] < ud[s]:
                    ud[s] = tmp_d[i]
            else:
                mark[c] = b
                slot[c] = u
                uc[u] = c
                ud[u] = tmp_d[i]
                u += 1
        order = np.argsort(ud[:u], kind="mergesort")
        for i in range(u):
            o = order[i]
            f_cell[out] = uc[o]
            zs = ud[o] * res
            f_dist[out] = zs
            f_ll[out] = beam_log_likelihood_of(z[b], zs, max_range, params)
            out += 1
        f_ptr[b + 1] = out
    return f_ptr, f_cell[:out].copy(), f_dist[:out].copy(), f_ll[:out].copy()


@njit(cache=True)
def invert_entries(f_ptr, f_cell, n_cells):
    """Inverse index: for each cell the entries (and so the beams) that depend on it.

    Returns ``(i_ptr, i_entry, e_beam)``.
    """
    nb = f_ptr.shape[0] - 1
    ne = f_cell.shape[0]
    e_beam = np.empty(ne, dtype=np.int32)
    for b in range(nb):
        for e in range(f_ptr[b], f_ptr[b + 1]):
            e_beam[e] = b
    i_ptr = np.zeros(n_cells + 1, dtype=np.int64)
    for e in range(ne):
        i_ptr[f_cell[e] + 1] += 1
    for c in range(n_cells):
        i_ptr[c + 1] += i_ptr[c]
    fill = i_ptr[:-1].copy()
    i_entry = np.empty(ne, dtype=np.int32)
    for e in range(ne):
        c = f_cell[e]
        i_entry[fill[c]] = e
        fill[c] += 1
    return i_ptr, i_entry, e_beam


@njit(cache=True)
def evaluate_beams(occ, f_ptr, f_cell, f_ll, far_ll, first, ll):
    """From scratch: each beam's first occupied entry (-1: none) and its log-likelihood."""
    nb = f_ptr.shape[0] - 1
    total = 0.0
    for b in range(nb):
        first[b] = -1
        ll[b] = far_ll[b]
        for e in range(f_ptr[b], f_ptr[b + 1]):
            if occ[f_cell[e]]:
                first[b] = e
                ll[b] = f_ll[e]
                break
        total += ll[b]
    return total


@njit(cache=True)
def _next_occupied(occ, f_cell, start, stop):
    for j in range(start, stop):
        if occ[f_cell[j]]:
            return j
    return -1


@njit(cache=True)
def flip_gain(c, occ, i_ptr, i_entry, e_beam, f_ptr, f_cell, f_ll, far_ll, first, ll, l0):
    """Change of the objective (eq. 9.25) if cell ``c`` flipped; only its beams are recomputed."""
    if occ[c]:
        # occupied -> free: beams whose first occupied cell is c now see the next one
        gain = -l0
        for i in range(i_ptr[c], i_ptr[c + 1]):
            e = i_entry[i]
            b = e_beam[e]
            if first[b] == e:
                j = _next_occupied(occ, f_cell, e + 1, f_ptr[b + 1])
                gain += (f_ll[j] if j >= 0 else far_ll[b]) - ll[b]
    else:
        # free -> occupied: beams that met c before their first occupied cell now stop at c
        gain = l0
        for i in range(i_ptr[c], i_ptr[c + 1]):
            e = i_entry[i]
            b = e_beam[e]
            if first[b] < 0 or e < first[b]:
                gain += f_ll[e] - ll[b]
    return gain


@njit(cache=True)
def apply_flip(c, occ, i_ptr, i_entry, e_beam, f_ptr, f_cell, f_ll, far_ll, first, ll):
    """Flip cell ``c`` and update the first occupied entry and log-likelihood of its beams."""
    if occ[c]:
        occ[c] = 0
        for i in range(i_ptr[c], i_ptr[c + 1]):
            e = i_entry[i]
            b = e_beam[e]
            if first[b] == e:
                j = _next_occupied(occ, f_cell, e + 1, f_ptr[b + 1])
                first[b] = j
                ll[b] = f_ll[j] if j >= 0 else far_ll[b]
    else:
        occ[c] = 1
        for i in range(i_ptr[c], i_ptr[c + 1]):
            e = i_entry[i]
            b = e_beam[e]
            if first[b] < 0 or e < first[b]:
                first[b] = e
                ll[b] = f_ll[e]


@njit(cache=True)
def sweep(cells, occ, i_ptr, i_entry, e_beam, f_ptr, f_cell, f_ll, far_ll, first, ll, l0, tol):
    """One pass of Table 9.3 over ``cells``: flip each cell whose flip raises the objective.

    Returns ``(flips, total_gain)``.
    """
    flips = 0
    total = 0.0
    for k in range(cells.shape[0]):
        c = cells[k]
        g = flip_gain(c, occ, i_ptr, i_entry, e_beam, f_ptr, f_cell, f_ll, far_ll, first, ll, l0)
        if g > tol:
            apply_flip(c, occ, i_ptr, i_entry, e_beam, f_ptr, f_cell, f_ll, far_ll, first, ll)
            flips += 1
            total += g
    return flips, total


@njit(cache=True)
def all_gains(cells, occ, i_ptr, i_entry, e_beam, f_ptr, f_cell, f_ll, far_ll, first, ll, l0):
    """Flip gain of every cell in ``cells`` without flipping any."""
    out = np.empty(cells.shape[0])
    for k in range(cells.shape[0]):
        out[k] = flip_gain(
            cells[k], occ, i_ptr, i_entry, e_beam, f_ptr, f_cell, f_ll, far_ll, first, ll, l0
        )
    return out
