"""Numba kernels of the occupancy grid: scan integration and ray casting (private).

The kernels take plain contiguous arrays and scalars (the scan kernels a tuple of them, see
:func:`classify_scan`) and trust their inputs: the public functions in
:mod:`probmap.grid.occupancy` and :mod:`probmap.grid.raycast` validate once.

Cell traversal is the one walk of :mod:`probmap.grid._traverse` (Amanatides and Woo 1987): the
segment walk for scan integration, the ray walk for ray casting.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from probmap.grid._traverse import cast_exact, walk_next, walk_start

_INF = np.inf


@njit(cache=True, inline="always")
def _walk_update(
    lo, stamp, sid, mark, gx0, gy0, gx1, gy1, include_last, delta, lmin, lmax, touched, tile
):  # pragma: no cover - compiled
    """Walk the cells from grid point (gx0, gy0) to (gx1, gy1) (in cell units), the last one only
    if ``include_last``, and add ``delta`` to each cell whose stamp is neither ``sid`` nor
    ``mark`` (clamped to ``[lmin, lmax]``), stamping it ``mark``; cells outside ``lo`` are
    skipped. With ``tile > 0`` also sets ``touched[iy // tile, ix // tile] = 1`` for every cell
    updated (``touched`` is not read otherwise). Returns the number of cells updated."""
    h, w = lo.shape
    ix, iy, ex, ey, sx, sy, tmx, tmy, tdx, tdy, n = walk_start(gx0, gy0, gx1, gy1, include_last)
    count = 0
    for _ in range(n):
        if 0 <= ix < w and 0 <= iy < h:
            st = stamp[iy, ix]
            if st != sid and st != mark:
                stamp[iy, ix] = mark
                if tile > 0:
                    touched[iy // tile, ix // tile] = 1
                v = lo[iy, ix] + delta
                if v < lmin:
                    v = lmin
                elif v > lmax:
                    v = lmax
                lo[iy, ix] = v
                count += 1
        ix, iy, tmx, tmy = walk_next(ix, iy, ex, ey, sx, sy, tmx, tmy, tdx, tdy)
    return count


@njit(cache=True, inline="always")
def classify_beam(
    r, a, px, py, ox, oy, inv, max_range, clear_range, thickness, inf_no_return, counts
):  # pragma: no cover - compiled
    """Classify one beam of range ``r`` (m) at world angle ``a`` (rad) from the sensor at
    ``(px, py)`` and give the grid points (cell units, origin ``(ox, oy)``, ``inv`` = 1 / res)
    that scan integration walks to.

    Returns ``(kind, ex, ey, tx, ty)``: kind 0 is a dropped reading (not positive, not finite,
    or at max range with no clearing), 1 a hit at ``(ex, ey)`` whose obstacle reaches
    ``(tx, ty)`` (``thickness`` metres further; the hit point itself when ``thickness`` is 0),
    2 a max-range reading cleared to ``(ex, ey)`` at ``clear_range``. With ``inf_no_return``
    a reading of ``+inf`` is a max-range reading (the RBPF's rule) instead of a dropped one
    (the grids' rule). Adds 1 to ``counts[0]`` (hits), ``counts[1]`` (max-range readings) or
    ``counts[2]`` (dropped readings). The one beam rule of :func:`integrate_scans` (grids and
    update counts), :func:`probmap.grid._semantic_kernels.integrate_labelled_scans` and
    :func:`probmap.slam.laser._match_kernels.integrate_window` (the RBPF's map windows).
    """
    if not (r > 0.0) or not math.isfinite(r):
        if not (inf_no_return and r == _INF):
            counts[2] += 1
            return 0, 0.0, 0.0, 0.0, 0.0
    c = math.cos(a)
    sn = math.sin(a)
    if r >= max_range:
        counts[1] += 1
        if clear_range > 0.0:
            ex = (px + clear_range * c - ox) * inv
            ey = (py + clear_range * sn - oy) * inv
            return 2, ex, ey, ex, ey
        return 0, 0.0, 0.0, 0.0, 0.0
    counts[0] += 1
    ex = (px + r * c - ox) * inv
    ey = (py + r * sn - oy) * inv
    if thickness > 0.0:
        tx = (px + (r + thickness) * c - ox) * inv
        ty = (py + (r + thickness) * sn - oy) * inv
        return 1, ex, ey, tx, ty
    return 1, ex, ey, ex, ey


@njit(cache=True, inline="always")
def classify_scan(s, scan, counts, kind, end, tip, inf_no_return):  # pragma: no cover - compiled
    """Classify every beam of scan ``s`` with :func:`classify_beam` (and its ``inf_no_return``
    rule), in beam order.

    ``scan`` is the tuple ``(ox, oy, res, poses, ranges, angles, angles_shared, max_range,
    clear_range, thickness)`` that the caller of a scan kernel builds once: the grid origin and
    cell size, the scans (poses (S, 3), ranges (S, B), angles (1, B) when ``angles_shared``,
    else (S, B)) and the sensor model's ranges (m). Both scan kernels, :func:`integrate_scans`
    and :func:`probmap.grid._semantic_kernels.integrate_labelled_scans`, take it as it is and
    hand it here: they differ only in what they do with the hits (the RBPF's
    :func:`probmap.slam.laser._match_kernels.integrate_window` builds one for its one scan).

    Fills ``kind[b]`` (0 dropped, 1 hit, 2 max-range), ``end[b]`` (the hit or cleared point) and
    ``tip[b]`` (where the obstacle ends) in cell units, counts the readings in ``counts[0:3]``,
    and returns the sensor's grid point ``(gx0, gy0)``, where every free-space walk starts.
    """  # noqa: D401
    ox, oy, res, poses, ranges, angles, angles_shared, max_range, clear_range, thickness = scan
    inv = 1.0 / res
    arow = 0 if angles_shared else s
    px = poses[s, 0]
    py = poses[s, 1]
    th = poses[s, 2]
    for b in range(ranges.shape[1]):
        k, ex, ey, tx, ty = classify_beam(
            ranges[s, b], th + angles[arow, b], px, py, ox, oy, inv, max_range, clear_range,
            thickness, inf_no_return, counts,
        )  # fmt: skip
        kind[b] = k
        end[b, 0] = ex
        end[b, 1] = ey
        tip[b, 0] = tx
        tip[b, 1] = ty
    return (px - ox) * inv, (py - oy) * inv


@njit(cache=True, inline="always")
def apply_scan(
    lo_hit, lo_free, stamp, sid, free_mark, gx0, gy0, kind, end, tip, d_hit, d_free, lmin, lmax,
    touched, tile,
):  # pragma: no cover - compiled  # fmt: skip
    """Update the cells of one scan classified by :func:`classify_scan`, each cell at most once.

    Hits are applied first, then free space, so that a hit cell is never also freed (the hit
    wins): pass 1 adds ``d_hit`` to ``lo_hit`` along every hit's obstacle (``end`` to ``tip``,
    both cells included) and stamps the cells ``sid``; pass 2 adds ``d_free`` to ``lo_free``
    along every kept beam from the sensor's grid point ``(gx0, gy0)`` up to, not including, the
    cell of its ``end``, and stamps the cells ``free_mark``. Only cells stamped neither ``sid``
    nor ``free_mark`` are updated; values are clamped to ``[lmin, lmax]`` (see
    :func:`_walk_update`, which also marks ``touched`` tiles when ``tile > 0``).

    The grids pass ``free_mark = sid``, the scan's id (the stamp keeps the last scan that touched
    each cell); the RBPF's windows, zeroed stamps with ``sid = 1`` and ``free_mark = 2`` (hit
    and freed cells told apart). Returns the number of cells updated.
    """
    count = 0
    for b in range(kind.shape[0]):
        if kind[b] == 1:
            count += _walk_update(
                lo_hit, stamp, sid, sid, end[b, 0], end[b, 1], tip[b, 0], tip[b, 1], True, d_hit,
                lmin, lmax, touched, tile,
            )  # fmt: skip
    for b in range(kind.shape[0]):
        if kind[b] == 0:
            continue
        count += _walk_update(
            lo_free, stamp, sid, free_mark, gx0, gy0, end[b, 0], end[b, 1], False, d_free, lmin,
            lmax, touched, tile,
        )  # fmt: skip
    return count


# Codes returned by integrate_one_scan; anything but SCAN_OK leaves the grid untouched.
SCAN_OK = 0
SCAN_BAD_POSE = 1  # a pose coordinate is not finite
SCAN_BAD_ANGLES_SHAPE = 2  # angles and ranges differ in length
SCAN_BAD_ANGLES = 3  # an angle is not finite
SCAN_BAD_MAX_RANGE = 4  # max_range is not > 0
SCAN_OUTSIDE = 5  # the scan leaves the grid (or its bounds are not finite): grow first


@njit(cache=True)
def integrate_one_scan(lo, stamp, sid, pose, ranges, angles, max_range, params):
    """Validate and integrate one scan (stamp ``sid``) into log-odds ``lo``, in place, in one call.

    The per-scan fast path of :meth:`probmap.grid.occupancy.OccupancyGrid.integrate_scan`: the
    same checks, bounding box and update as the batch path (:func:`scan_bounds` then
    :func:`integrate_scans` on one scan), with few arguments so that the call itself is cheap.
    ``pose`` (3,), ``ranges`` (B,) and ``angles`` (B,) are float64; ``params`` is float64
    ``[ox, oy, res, max_clear_range (< 0 for None), thickness, d_hit, d_free, lmin, lmax]``.

    Returns ``(code, hits, max-range readings, dropped readings, cell updates)``. ``code`` is
    ``SCAN_OK`` when the scan was integrated; any other code (see the ``SCAN_*`` constants) means
    nothing was changed, and the caller takes the general path, which raises or grows the grid.
    """
    for k in range(3):
        if not math.isfinite(pose[k]):
            return SCAN_BAD_POSE, 0, 0, 0, 0
    n = ranges.shape[0]
    if angles.shape[0] != n:
        return SCAN_BAD_ANGLES_SHAPE, 0, 0, 0, 0
    for b in range(n):
        if not math.isfinite(angles[b]):
            return SCAN_BAD_ANGLES, 0, 0, 0, 0
    if not max_range > 0.0:
        return SCAN_BAD_MAX_RANGE, 0, 0, 0, 0
    ox = params[0]
    oy = params[1]
    res = params[2]
    max_clear = params[3]
    thickness = params[4]
    # effective_clear_range in probmap.grid.occupancy
    if max_clear < 0.0:
        clear_range = max_range if math.isfinite(max_range) else 0.0
    else:
        clear_range = min(max_clear, max_range)
    P = np.empty((1, 3))
    for k in range(3):
        P[0, k] = pose[k]
    R = np.empty((1, n))
    A = np.empty((1, n))
    for b in range(n):
        R[0, b] = ranges[b]
        A[0, b] = angles[b]
    box = np.empty(4)
    scan_bounds(P, R, A, True, max_range, clear_range, thickness, box)
    h, w = lo.shape
    for k in range(4):
        if not math.isfinite(box[k]):
            return SCAN_OUTSIDE, 0, 0, 0, 0
    # GridSpec.enclosing: the grid stays as it is only if every corner's cell lies in it. The
    # cell indexes stay floats (np.floor): an index too large for an integer must not wrap round.
    if (
        h == 0
        or w == 0
        or np.floor((box[0] - ox) / res) < 0.0
        or np.floor((box[1] - ox) / res) >= w
        or np.floor((box[2] - oy) / res) < 0.0
        or np.floor((box[3] - oy) / res) >= h
    ):
        return SCAN_OUTSIDE, 0, 0, 0, 0
    counts = np.zeros(4, np.int64)
    scan = (ox, oy, res, P, R, A, True, max_range, clear_range, thickness)
    integrate_scans(lo, lo, stamp, sid, scan, params[5], params[6], params[7], params[8], counts)
    return SCAN_OK, counts[0], counts[1], counts[2], counts[3]


@njit(cache=True)
def integrate_scans(
    lo_hit, lo_free, stamp, sid0, scan, d_hit, d_free, lmin, lmax, counts
):  # pragma: no cover - compiled
    """Integrate scans ``s`` with stamps ``sid0 + s`` (in place): hits add ``d_hit`` to
    ``lo_hit``, free space ``d_free`` to ``lo_free``, each cell clamped to ``[lmin, lmax]``.
    ``scan`` holds the grid geometry, the scans and the sensor's ranges (see :func:`classify_scan`).

    For a log-odds grid ``lo_hit`` and ``lo_free`` are the same array. Passing two count
    arrays with ``d_hit = d_free = 1`` and unreachable bounds counts, per cell, the scans that
    hit it and that crossed it, without prior or clamping (for summing increments across
    processes: :func:`probmap.grid.increments.integrate_increments`).

    ``counts`` (int64[4]) accumulates: hits, max-range readings, dropped readings, cell updates.
    Each scan goes through :func:`apply_scan`: hits first, then free space, so that within one
    scan a hit cell is never also freed and every cell changes at most once (the stamp records
    the last scan that touched it).
    """
    n_scans, n_beams = scan[4].shape  # the ranges (S, B)
    end = np.empty((n_beams, 2))
    tip = np.empty((n_beams, 2))
    kind = np.empty(n_beams, np.int8)
    no_tiles = np.zeros((1, 1), np.uint8)  # apply_scan's tile marks: not kept here (tile 0)
    for s in range(n_scans):
        sid = sid0 + s
        gx0, gy0 = classify_scan(s, scan, counts, kind, end, tip, False)
        counts[3] += apply_scan(
            lo_hit, lo_free, stamp, sid, sid, gx0, gy0, kind, end, tip, d_hit, d_free, lmin, lmax,
            no_tiles, 0,
        )  # fmt: skip


@njit(cache=True)
def scan_bounds(poses, ranges, angles, angles_shared, max_range, clear_range, thickness, out):
    """World bounding box ``out = [xmin, xmax, ymin, ymax]`` of the poses and of every point a scan
    can touch (hits plus thickness, and max-range readings cleared to ``clear_range``)."""  # noqa: D401
    n_scans, n_beams = ranges.shape
    xmin = _INF
    ymin = _INF
    xmax = -_INF
    ymax = -_INF
    for s in range(n_scans):
        px = poses[s, 0]
        py = poses[s, 1]
        th = poses[s, 2]
        xmin = min(xmin, px)
        xmax = max(xmax, px)
        ymin = min(ymin, py)
        ymax = max(ymax, py)
        arow = 0 if angles_shared else s
        for b in range(n_beams):
            r = ranges[s, b]
            if not (r > 0.0) or not math.isfinite(r):
                continue
            if r >= max_range:
                if clear_range <= 0.0:
                    continue
                d = clear_range
            else:
                d = r + thickness
            a = th + angles[arow, b]
            x = px + d * math.cos(a)
            y = py + d * math.sin(a)
            xmin = min(xmin, x)
            xmax = max(xmax, x)
            ymin = min(ymin, y)
            ymax = max(ymax, y)
    out[0] = xmin
    out[1] = xmax
    out[2] = ymin
    out[3] = ymax


@njit(cache=True)
def cast_rays(occ, ox, oy, res, poses, angles, max_range, out):  # pragma: no cover - compiled
    """Range along each beam to the first occupied cell of boolean grid ``occ`` (H, W).

    ``out[p, b]`` is the distance in metres from the sensor at ``poses[p]`` to where beam ``b``
    enters the first occupied cell, or ``max_range`` when none is met within ``max_range`` (or the
    beam leaves the grid). A sensor inside an occupied cell reads 0.
    """
    n_poses = poses.shape[0]
    n_beams = angles.shape[0]
    limit = max_range / res
    for p in range(n_poses):
        px = (poses[p, 0] - ox) / res
        py = (poses[p, 1] - oy) / res
        for b in range(n_beams):
            a = poses[p, 2] + angles[b]
            t = cast_exact(occ, px, py, math.cos(a), math.sin(a), limit)
            out[p, b] = min(t * res, max_range) if t < limit else max_range


@njit(cache=True)
def counts_to_log_odds(hits, frees, l0, d_hit, d_free, lmin, lmax, lo, seen):
    """``lo = clip(l0 + hits d_hit + frees d_free, lmin, lmax)`` (float64 sum, stored in ``lo``'s
    dtype) and ``seen = hits > 0 or frees > 0``, cell by cell in one pass."""  # noqa: D401
    h, w = hits.shape
    for i in range(h):
        for j in range(w):
            a = hits[i, j]
            b = frees[i, j]
            v = l0 + a * d_hit + b * d_free
            if v < lmin:
                v = lmin
            elif v > lmax:
                v = lmax
            lo[i, j] = v
            seen[i, j] = a > 0 or b > 0
