"""Numba kernels for multi-class (semantic) occupancy grids (private).

The kernels take plain contiguous arrays and scalars (and the scan tuple of
:func:`probmap.grid._kernels.classify_scan`) and trust their inputs: the public class
:class:`probmap.grid.semantic.SemanticGrid` validates once. Cells are visited by the same
Amanatides-Woo walk as the binary grid (:func:`probmap.grid._traverse.walk_start` and
:func:`~probmap.grid._traverse.walk_next`), so with one class the two grids touch exactly the same
cells in the same order and add exactly the same float64 increments to the same float32 values.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from probmap.grid._kernels import classify_scan
from probmap.grid._traverse import walk_next, walk_start


@njit(cache=True, inline="always")
def _add_clamped(lo, iy, ix, delta, lmin, lmax):  # pragma: no cover - compiled
    """``lo[iy, ix, :] = clamp(lo[iy, ix, :] + delta)``, per class, in float64 then stored.

    ``lmin`` and ``lmax`` are tuples (up to 8 classes) or arrays: a tuple's length, the number of
    classes, is part of the compiled type, so the class loop is unrolled and the bounds stay in
    registers."""
    for k in range(len(lmin)):
        v = lo[iy, ix, k] + delta[k]
        if v < lmin[k]:
            v = lmin[k]
        elif v > lmax[k]:
            v = lmax[k]
        lo[iy, ix, k] = v


@njit(cache=True)
def integrate_labelled_scans(
    lo, stamp, slot, sid0, scan, qrow, q_hit, d_hit, d_free, l_prior, lmin, lmax, counts
):  # pragma: no cover - compiled
    """Integrate labelled scans ``s`` with stamps ``sid0 + s`` into log odds ``lo`` (in place).

    Parameters (all trusted)
    ------------------------
    lo : float32 (H, W, K)
        Log odds ``log p(k) / p(0)`` of classes 1..K per cell.
    stamp : int32 (H, W)
        Last scan that updated each cell (the once-per-scan rule).
    slot : int32 (H, W)
        Scratch: index of a cell in this scan's list of endpoint cells (valid only for cells
        stamped with the current scan during the endpoint pass).
    sid0 : int
        Stamp of scan 0; scan ``s`` has stamp ``sid0 + s``.
    scan : tuple
        The grid geometry, the scans and the sensor's ranges, as
        :func:`probmap.grid._kernels.integrate_scans` takes them (see
        :func:`~probmap.grid._kernels.classify_scan`).
    qrow : int64 (S, B)
        Row of ``q_hit`` / ``d_hit`` holding the evidence of each beam's endpoint.
    q_hit : float64 (R, K)
        ``p(m = k | z)`` for classes 1..K at an endpoint (class 0 gets the rest).
    d_hit : float64 (R, K)
        Increment of a cell hit by endpoints of that one row only: inverse term plus prior term.
    d_free : tuple of K floats (K <= 8) or float64 (K,)
        Increment of a cell crossed by a beam.
    l_prior : float64 (K,)
        Prior log odds ``log p(k) / p(0)`` (subtracted from pooled inverse terms).
    lmin, lmax : tuples of K floats (K <= 8) or float64 (K,)
        Clamping bounds per class (tuples: the kernel is compiled once per K).
    counts : int64 (4,)
        Accumulates hits, max-range readings, dropped readings and cell updates.

    Notes
    -----
    Pass 1 walks each hit's endpoint cells (with the obstacle thickness) and gathers, per cell,
    the endpoint evidence rows that reach it in this scan. Pass 2 applies one update per gathered
    cell: the row's precomputed increment when every endpoint in the cell carried the same
    evidence, else the inverse term of the average of their class distributions (a linear opinion
    pool). Pass 3 frees the cells along every beam that were not updated in this scan.
    """
    n_scans, n_beams = scan[4].shape  # the ranges (S, B)
    n_cls = lo.shape[2]
    h = lo.shape[0]
    w = lo.shape[1]
    end = np.empty((n_beams, 2))
    tip = np.empty((n_beams, 2))
    kind = np.empty(n_beams, np.int8)
    cap = max(16, 2 * n_beams)
    cell_y = np.empty(cap, np.int64)
    cell_x = np.empty(cap, np.int64)
    row = np.empty(cap, np.int64)
    cnt = np.empty(cap, np.int64)
    mixed = np.empty(cap, np.bool_)
    acc = np.empty((cap, n_cls))
    delta = np.empty(n_cls)
    n_updates = 0  # a local counter: a store to counts[] per cell would stay in the loop
    for s in range(n_scans):
        sid = sid0 + s
        gx0, gy0 = classify_scan(s, scan, counts, kind, end, tip, False)
        n_cells = 0
        # pass 1: gather the endpoint evidence per cell
        for b in range(n_beams):
            if kind[b] != 1:
                continue
            q = qrow[s, b]
            ix, iy, lx, ly, sx, sy, tmx, tmy, tdx, tdy, n = walk_start(
                end[b, 0], end[b, 1], tip[b, 0], tip[b, 1], True
            )
            for _ in range(n):
                if 0 <= ix < w and 0 <= iy < h:
                    if stamp[iy, ix] != sid:
                        stamp[iy, ix] = sid
                        if n_cells == cap:  # grow the gather buffers
                            cap *= 2
                            cell_y = _grow_i(cell_y, cap)
                            cell_x = _grow_i(cell_x, cap)
                            row = _grow_i(row, cap)
                            cnt = _grow_i(cnt, cap)
                            mixed2 = np.empty(cap, np.bool_)
                            mixed2[:n_cells] = mixed[:n_cells]
                            mixed = mixed2
                            acc2 = np.empty((cap, n_cls))
                            acc2[:n_cells] = acc[:n_cells]
                            acc = acc2
                        slot[iy, ix] = n_cells
                        cell_y[n_cells] = iy
                        cell_x[n_cells] = ix
                        row[n_cells] = q
                        cnt[n_cells] = 1
                        mixed[n_cells] = False
                        n_cells += 1
                    else:
                        j = slot[iy, ix]
                        if not mixed[j]:
                            same = row[j] == q
                            if not same:
                                same = True
                                for k in range(n_cls):
                                    if q_hit[row[j], k] != q_hit[q, k]:
                                        same = False
                                        break
                            if same:
                                cnt[j] += 1
                            else:
                                mixed[j] = True
                                for k in range(n_cls):
                                    acc[j, k] = cnt[j] * q_hit[row[j], k] + q_hit[q, k]
                                cnt[j] += 1
                        else:
                            for k in range(n_cls):
                                acc[j, k] += q_hit[q, k]
                            cnt[j] += 1
                ix, iy, tmx, tmy = walk_next(ix, iy, lx, ly, sx, sy, tmx, tmy, tdx, tdy)
        # pass 2: one update per endpoint cell
        for j in range(n_cells):
            if mixed[j]:
                # inverse term of the pooled distribution: log(qk) - log(q0), q0 = 1 - sum(qk)
                tot = 0.0
                for k in range(n_cls):
                    acc[j, k] /= cnt[j]
                    tot += acc[j, k]
                log_q0 = math.log1p(-tot)
                for k in range(n_cls):
                    delta[k] = math.log(acc[j, k]) - log_q0 - l_prior[k]
                _add_clamped(lo, cell_y[j], cell_x[j], delta, lmin, lmax)
            else:
                _add_clamped(lo, cell_y[j], cell_x[j], d_hit[row[j]], lmin, lmax)
        n_updates += n_cells
        # pass 3: free space along every beam up to (not including) its last cell
        for b in range(n_beams):
            if kind[b] == 0:
                continue
            ix, iy, lx, ly, sx, sy, tmx, tmy, tdx, tdy, n = walk_start(
                gx0, gy0, end[b, 0], end[b, 1], False
            )
            for _ in range(n):
                if 0 <= ix < w and 0 <= iy < h:
                    if stamp[iy, ix] != sid:
                        stamp[iy, ix] = sid
                        _add_clamped(lo, iy, ix, d_free, lmin, lmax)
                        n_updates += 1
                ix, iy, tmx, tmy = walk_next(ix, iy, lx, ly, sx, sy, tmx, tmy, tdx, tdy)
    counts[3] += n_updates


@njit(cache=True)
def _grow_i(a, cap):  # pragma: no cover - compiled
    out = np.empty(cap, a.dtype)
    out[: a.shape[0]] = a
    return out
