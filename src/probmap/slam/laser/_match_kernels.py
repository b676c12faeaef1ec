"""Numba kernels of the scan matcher and of the tiled particle maps (private).

Every kernel takes contiguous arrays and scalars; the public functions in
:mod:`probmap.slam.laser.scan_matching` and :mod:`probmap.slam.laser._tiles` validate inputs once.
Field convention: ``field[iy, ix]`` is the value at the centre of cell ``(ix, iy)``, whose
lower-left corner is ``(ox + ix * res, oy + iy * res)``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from probmap.grid._kernels import apply_scan, classify_scan


@njit(cache=True)
def bilinear(field, ox, oy, res, px, py):  # pragma: no cover - compiled
    """Bilinear value of ``field`` at world point (px, py) and its gradient (per metre).

    Outside the field the value and the gradient are 0.
    """
    h, w = field.shape
    u = (px - ox) / res - 0.5
    v = (py - oy) / res - 0.5
    i0 = math.floor(u)
    j0 = math.floor(v)
    if i0 < 0 or j0 < 0 or i0 + 1 >= w or j0 + 1 >= h:
        return 0.0, 0.0, 0.0
    fx = u - i0
    fy = v - j0
    f00 = field[j0, i0]
    f10 = field[j0, i0 + 1]
    f01 = field[j0 + 1, i0]
    f11 = field[j0 + 1, i0 + 1]
    val = (1 - fy) * ((1 - fx) * f00 + fx * f10) + fy * ((1 - fx) * f01 + fx * f11)
    dx = ((1 - fy) * (f10 - f00) + fy * (f11 - f01)) / res
    dy = ((1 - fx) * (f01 - f00) + fx * (f11 - f10)) / res
    return val, dx, dy


@njit(cache=True, inline="always")
def _point_term(field, ox, oy, res, px, py, x, y, c, s):  # pragma: no cover - compiled
    """Field value at the point ``(px, py)`` (sensor frame) seen from pose ``(x, y, theta)``
    with ``(c, s) = (cos theta, sin theta)``, and its derivatives w.r.t. ``x``, ``y`` and
    ``theta``: ``(M, dM/dx, dM/dy, dM/dtheta)``."""
    qx = x + c * px - s * py
    qy = y + s * px + c * py
    val, gx, gy = bilinear(field, ox, oy, res, qx, qy)
    return val, gx, gy, gx * (-s * px - c * py) + gy * (c * px - s * py)


@njit(cache=True)
def point_terms(field, ox, oy, res, pts, x, y, th, out):  # pragma: no cover - compiled
    """Per point: field value and its derivative w.r.t. the pose, ``out[i] = (M, dM/dx,
    dM/dy, dM/dtheta)`` for the point ``pts[i]`` (sensor frame) seen from pose (x, y, th)."""
    c = math.cos(th)
    s = math.sin(th)
    for i in range(pts.shape[0]):
        val, gx, gy, gt = _point_term(field, ox, oy, res, pts[i, 0], pts[i, 1], x, y, c, s)
        out[i, 0] = val
        out[i, 1] = gx
        out[i, 2] = gy
        out[i, 3] = gt


@njit(cache=True)
def gauss_newton_terms(field, ox, oy, res, pts, x, y, th, g, H):  # pragma: no cover
    """Accumulate the normal equations of ``sum_i r_i^2 / 2`` with ``r_i = 1 - M(q_i)``.

    ``g = J^T r`` (gradient), ``H = J^T J`` (Gauss-Newton Hessian); returns ``sum_i M(q_i)``
    and ``sum_i r_i^2``.
    """
    c = math.cos(th)
    s = math.sin(th)
    for a in range(3):
        g[a] = 0.0
        for b in range(3):
            H[a, b] = 0.0
    score = 0.0
    sq = 0.0
    J = np.empty(3)
    for i in range(pts.shape[0]):
        val, gx, gy, gt = _point_term(field, ox, oy, res, pts[i, 0], pts[i, 1], x, y, c, s)
        r = 1.0 - val
        J[0] = -gx
        J[1] = -gy
        J[2] = -gt
        for a in range(3):
            g[a] += J[a] * r
            for b in range(3):
                H[a, b] += J[a] * J[b]
        score += val
        sq += r * r
    return score, sq


@njit(cache=True)
def nearest_score(field, ox, oy, res, pts, x, y, th):  # pragma: no cover - compiled
    """Sum of the field at the cells holding the points (nearest cell, 0 outside)."""
    h, w = field.shape
    c = math.cos(th)
    s = math.sin(th)
    total = 0.0
    for i in range(pts.shape[0]):
        qx = x + c * pts[i, 0] - s * pts[i, 1]
        qy = y + s * pts[i, 0] + c * pts[i, 1]
        ix = math.floor((qx - ox) / res)
        iy = math.floor((qy - oy) / res)
        if 0 <= ix < w and 0 <= iy < h:
            total += field[iy, ix]
    return total


@njit(cache=True, inline="always")
def _cell_tables(
    pts, c, s, x0, y0, nl, lin_step, ox, oy, res, h, w, cols, rows
):  # pragma: no cover - compiled
    """Per point ``i`` rotated by ``(c, s) = (cos, sin)`` of a heading: its cell column at every
    x offset ``k`` of the search box (``cols[k, i]``) and its row at every y offset
    (``rows[k, i]``), -1 outside the field. The same expressions as a direct evaluation
    (:func:`nearest_score`), so table scores are identical to it."""
    n = pts.shape[0]
    m = 2 * nl + 1
    for i in range(n):
        rx = c * pts[i, 0] - s * pts[i, 1]
        ry = s * pts[i, 0] + c * pts[i, 1]
        for k in range(m):
            ix = math.floor((x0 + (k - nl) * lin_step + rx - ox) / res)
            iy = math.floor((y0 + (k - nl) * lin_step + ry - oy) / res)
            cols[k, i] = ix if 0 <= ix < w else -1
            rows[k, i] = iy if 0 <= iy < h else -1


@njit(cache=True, inline="always")
def _table_score(field, cx, ry):  # pragma: no cover - compiled
    """Nearest-cell score of the points at cell columns ``cx`` and rows ``ry`` (-1: outside)."""
    total = 0.0
    for i in range(cx.shape[0]):
        ix = cx[i]
        iy = ry[i]
        if ix >= 0 and iy >= 0:
            total += field[iy, ix]
    return total


@njit(cache=True)
def correlative_search(
    field, ox, oy, res, pts, x0, y0, th0, lin_window, lin_step, ang_window, ang_step, out
):  # pragma: no cover - compiled
    """Exhaustive search of the nearest-cell score over a box of poses around (x0, y0, th0).

    ``out`` receives the best ``(x, y, theta, score)``; of equal scores the first visited wins
    (loops: angle, then x, then y, each from the most negative offset).

    Per heading the cell columns of every point at every x offset (and the rows at every y
    offset) are computed once, so the innermost loop is a table look-up per point (Olson 2009's
    decomposition of the search into rotations and translations).
    """
    nl = int(round(lin_window / lin_step))
    na = int(round(ang_window / ang_step))
    h, w = field.shape
    best = -1.0
    bx = x0
    by = y0
    bt = th0
    n = pts.shape[0]
    m = 2 * nl + 1
    cols = np.empty((m, n), dtype=np.int64)
    rows = np.empty((m, n), dtype=np.int64)
    for ka in range(-na, na + 1):
        th = th0 + ka * ang_step
        c = math.cos(th)
        s = math.sin(th)
        _cell_tables(pts, c, s, x0, y0, nl, lin_step, ox, oy, res, h, w, cols, rows)
        for kx in range(m):
            cx = cols[kx]
            for ky in range(m):
                total = _table_score(field, cx, rows[ky])
                if total > best:  # strictly better: the first of equals wins
                    best = total
                    bx = x0 + (kx - nl) * lin_step
                    by = y0 + (ky - nl) * lin_step
                    bt = th
    out[0] = bx
    out[1] = by
    out[2] = bt
    out[3] = best


@njit(cache=True)
def correlative_moments(
    field,
    ox,
    oy,
    res,
    pts,
    x0,
    y0,
    th0,
    lin_window,
    lin_step,
    ang_window,
    ang_step,
    temperature,
    out,
):  # pragma: no cover - compiled
    """Moments of the search box's poses weighted by ``exp((S - S_max) / temperature)``, with
    ``S`` the nearest-cell score (Olson 2009: the correlative search as a distribution).

    ``out[0]`` receives ``S_max``; ``out[1:4]`` the weighted mean offset ``(dx, dy, dtheta)``
    from ``(x0, y0, th0)``; ``out[4:10]`` the weighted covariance ``(xx, xy, xt, yy, yt, tt)``;
    ``out[10:13]`` the best pose, the first of equals as in :func:`correlative_search`.
    The running sums are rescaled whenever a larger score appears (one pass).
    """
    nl = int(round(lin_window / lin_step))
    na = int(round(ang_window / ang_step))
    h, w = field.shape
    n = pts.shape[0]
    m = 2 * nl + 1
    cols = np.empty((m, n), dtype=np.int64)
    rows = np.empty((m, n), dtype=np.int64)
    best = -1.0
    acc = np.zeros(10)  # weight, 3 first moments, 6 second moments
    for ka in range(-na, na + 1):
        th = th0 + ka * ang_step
        c = math.cos(th)
        s = math.sin(th)
        _cell_tables(pts, c, s, x0, y0, nl, lin_step, ox, oy, res, h, w, cols, rows)
        dt = ka * ang_step
        for kx in range(m):
            cx = cols[kx]
            dx = (kx - nl) * lin_step
            for ky in range(m):
                total = _table_score(field, cx, rows[ky])
                if total > best:
                    scale = math.exp((best - total) / temperature) if best >= 0.0 else 0.0
                    for j in range(10):
                        acc[j] *= scale
                    best = total
                    out[10] = x0 + dx
                    out[11] = y0 + (ky - nl) * lin_step
                    out[12] = th
                dy = (ky - nl) * lin_step
                wgt = math.exp((total - best) / temperature)
                acc[0] += wgt
                acc[1] += wgt * dx
                acc[2] += wgt * dy
                acc[3] += wgt * dt
                acc[4] += wgt * dx * dx
                acc[5] += wgt * dx * dy
                acc[6] += wgt * dx * dt
                acc[7] += wgt * dy * dy
                acc[8] += wgt * dy * dt
                acc[9] += wgt * dt * dt
    out[0] = best
    mx = acc[1] / acc[0]
    my = acc[2] / acc[0]
    mt = acc[3] / acc[0]
    out[1] = mx
    out[2] = my
    out[3] = mt
    out[4] = acc[4] / acc[0] - mx * mx
    out[5] = acc[5] / acc[0] - mx * my
    out[6] = acc[6] / acc[0] - mx * mt
    out[7] = acc[7] / acc[0] - my * my
    out[8] = acc[8] / acc[0] - my * mt
    out[9] = acc[9] / acc[0] - mt * mt


@njit(cache=True)
def solve3(A, b, out):  # pragma: no cover - compiled
    """Solve the 3 x 3 system ``A out = b`` by Gaussian elimination with partial pivoting;
    returns False when ``A`` is singular."""
    M = np.empty((3, 4))
    for i in range(3):
        for j in range(3):
            M[i, j] = A[i, j]
        M[i, 3] = b[i]
    for col in range(3):
        piv = col
        for r in range(col + 1, 3):
            if abs(M[r, col]) > abs(M[piv, col]):
                piv = r
        if M[piv, col] == 0.0:
            return False
        if piv != col:
            for j in range(4):
                t = M[col, j]
                M[col, j] = M[piv, j]
                M[piv, j] = t
        for r in range(col + 1, 3):
            f = M[r, col] / M[col, col]
            for j in range(col, 4):
                M[r, j] -= f * M[col, j]
    for i in range(2, -1, -1):
        acc = M[i, 3]
        for j in range(i + 1, 3):
            acc -= M[i, j] * out[j]
        out[i] = acc / M[i, i]
    return True


@njit(cache=True)
def refine_pose(
    field, ox, oy, res, pts, x, y, th, iterations, max_lin, max_ang, pose, H
):  # pragma: no cover - compiled
    """Gauss-Newton refinement (see :func:`probmap.slam.laser.scan_matching.refine`) in one call.

    Writes the final pose into ``pose`` (3,) and its ``J^T J`` into ``H`` (3, 3); returns the
    iterations taken and the final ``sum r^2``.
    """
    g = np.empty(3)
    g2 = np.empty(3)
    H2 = np.empty((3, 3))
    A = np.empty((3, 3))
    step = np.empty(3)
    px = x
    py = y
    pt = th
    _, sq = gauss_newton_terms(field, ox, oy, res, pts, px, py, pt, g, H)
    taken = 0
    for it in range(1, iterations + 1):
        for a in range(3):
            for b in range(3):
                A[a, b] = H[a, b] + (1e-9 if a == b else 0.0)
            A[a, a] += 1e-6 * H[a, a]
            g2[a] = -g[a]
        if not solve3(A, g2, step):
            break
        shrink = max(math.hypot(step[0], step[1]) / max_lin, abs(step[2]) / max_ang)
        if shrink > 1.0:
            for a in range(3):
                step[a] /= shrink
        cx = px + step[0]
        cy = py + step[1]
        ct = pt + step[2]
        _, sq2 = gauss_newton_terms(field, ox, oy, res, pts, cx, cy, ct, g2, H2)
        if not sq2 < sq:
            break
        taken = it
        px, py, pt, sq = cx, cy, ct, sq2
        for a in range(3):
            g[a] = g2[a]
            for b in range(3):
                H[a, b] = H2[a, b]
        if abs(step[0]) + abs(step[1]) < 1e-5 and abs(step[2]) < 1e-5:
            break
    pose[0] = px
    pose[1] = py
    pose[2] = pt
    return taken, sq


@njit(cache=True)
def integrate_window(
    lo,
    stamp,
    ox,
    oy,
    res,
    x,
    y,
    th,
    ranges,
    angles,
    max_range,
    clear_range,
    l_hit,
    l_miss,
    l_min,
    l_max,
    tile,
    touched,
):  # pragma: no cover - compiled
    """Integrate one scan into a dense log-odds window (Table 9.1), each cell once.

    Endpoints (``r < max_range``) get ``l_hit`` first, then cells crossed by any beam and not
    hit get ``l_miss`` (hit wins); values are clamped to ``[l_min, l_max]``. Max-range readings,
    ``+inf`` included, clear up to ``clear_range`` (taken as it is: not capped at ``max_range``;
    0 clears nothing); NaN and non-positive readings are dropped. ``stamp`` (same shape, zero on
    entry) marks the cells updated (1 = hit, 2 = miss); ``touched[iy // tile, ix // tile]`` is set
    to 1 for every updated cell (zero it on entry). Cells outside the window are ignored.

    The occupancy grid's kernels do the work: :func:`probmap.grid._kernels.classify_scan` (with
    ``+inf`` as a no-return reading) and :func:`probmap.grid._kernels.apply_scan` (with no
    obstacle thickness: only the endpoint's cell is hit), so the cells and the updates are those
    of :class:`~probmap.grid.occupancy.OccupancyGrid` for the same beam.
    """
    nb = ranges.shape[0]
    P = np.empty((1, 3))
    P[0, 0] = x
    P[0, 1] = y
    P[0, 2] = th
    R = np.empty((1, nb))
    A = np.empty((1, nb))
    for b in range(nb):
        R[0, b] = ranges[b]
        A[0, b] = angles[b]
    scan = (ox, oy, res, P, R, A, True, max_range, clear_range, 0.0)
    kind = np.empty(nb, np.int8)
    end = np.empty((nb, 2))
    tip = np.empty((nb, 2))
    counts = np.zeros(4, np.int64)  # classify_scan's reading counts, not needed here
    gx0, gy0 = classify_scan(0, scan, counts, kind, end, tip, True)
    apply_scan(
        lo, lo, stamp, 1, 2, gx0, gy0, kind, end, tip, l_hit, l_miss, l_min, l_max, touched, tile
    )


@njit(cache=True)
def splat_field(lo, threshold, radius, inv_two_sigma2_cells, out):  # pragma: no cover
    """Match field of a log-odds window: ``out = exp(-d^2 / (2 sigma^2))`` with ``d`` the
    distance in cells to the nearest cell with ``lo > threshold``, 0 beyond ``radius`` cells.

    Each occupied cell writes the maximum of its kernel into its neighbourhood, so the cost is
    (occupied cells) x (2 radius + 1)^2 instead of a distance transform of the whole window.
    The kernel is tabulated once (0 marks offsets beyond ``radius``).
    """
    h, w = lo.shape
    for iy in range(h):
        for ix in range(w):
            out[iy, ix] = 0.0
    r2 = radius * radius
    side = 2 * radius + 1
    kern = np.zeros((side, side))
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            d2 = dx * dx + dy * dy
            if d2 <= r2:
                kern[dy + radius, dx + radius] = math.exp(-d2 * inv_two_sigma2_cells)
    for iy in range(h):
        for ix in range(w):
            if lo[iy, ix] > threshold:
                y_lo = max(iy - radius, 0)
                y_hi = min(iy + radius, h - 1)
                x_lo = max(ix - radius, 0)
                x_hi = min(ix + radius, w - 1)
                for y in range(y_lo, y_hi + 1):
                    krow = y - iy + radius
                    for x in range(x_lo, x_hi + 1):
                        v = kern[krow, x - ix + radius]
                        if v > out[y, x]:
                            out[y, x] = v


@njit(cache=True)
def splat_cells(iys, ixs, radius, inv_two_sigma2_cells, out):  # pragma: no cover - compiled
    """Raise ``out`` to the match-field kernel of each cell ``(ixs[k], iys[k])`` (cells that
    became occupied): the incremental twin of :func:`splat_field`, same kernel and same max
    rule, so splatting new cells onto a field equals recomputing it when no cell was freed."""
    h, w = out.shape
    r2 = radius * radius
    for k in range(iys.shape[0]):
        iy = iys[k]
        ix = ixs[k]
        for y in range(max(iy - radius, 0), min(iy + radius, h - 1) + 1):
            dy = y - iy
            for x in range(max(ix - radius, 0), min(ix + radius, w - 1) + 1):
                dx = x - ix
                d2 = dx * dx + dy * dy
                if d2 <= r2:
                    v = math.exp(-d2 * inv_two_sigma2_cells)
                    if v > out[y, x]:
                        out[y, x] = v


@njit(cache=True)
def log_likelihoods(field, ox, oy, res, pts, poses, floor, out):  # pragma: no cover
    """``out[k] = sum_i max(log M(q_i(poses[k])), floor)`` with bilinear ``M``."""
    for k in range(poses.shape[0]):
        x = poses[k, 0]
        y = poses[k, 1]
        c = math.cos(poses[k, 2])
        s = math.sin(poses[k, 2])
        total = 0.0
        for i in range(pts.shape[0]):
            qx = x + c * pts[i, 0] - s * pts[i, 1]
            qy = y + s * pts[i, 0] + c * pts[i, 1]
            val, gx, gy = bilinear(field, ox, oy, res, qx, qy)
            if val > 0.0:
                total += max(math.log(val), floor)
            else:
                total += floor
        out[k] = total
