"""Numba kernels of the branch-and-bound loop-closure search (private).

The public functions in :mod:`probmap.slam.laser.loop_closure` validate every input once; these
kernels take contiguous arrays and scalars only.

Conventions
-----------
``base[iy, ix]`` is the match field at the centre of cell ``(ix, iy)``, float64, values in
[0, 1]. The max-grid of depth ``h >= 1`` is stored as uint8 *codes* ``c`` whose value is
``table[c]`` (``table = arange(256) / 255``) in one flat buffer ``buf``, laid out by the int64
table ``levels[h] = (offset, H + pad, W + pad, pad)`` with ``pad = 2**h - 1`` extra rows and
columns on the low side; element ``[iy + pad, ix + pad]`` (row-major, from ``offset``) bounds
the base over the block of cells ``[ix, ix + 2**h) x [iy, iy + 2**h)`` (cells outside the grid
count 0). Level 0 is the base itself. The *cell tables* hold, per heading ``a`` of the search,
the cell ``floor((c + R(theta_a) p - origin) / res)`` of every point seen from the window's
centre ``c``; the candidate at integer offset ``(kx, ky)`` puts point ``i`` in cell
``(cx[a, i] + kx, cy[a, i] + ky)``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def quantize_up(values, table, out):  # pragma: no cover - compiled
    """``out[iy, ix]`` = the smallest code ``c`` with ``table[c] >= values[iy, ix]``.

    Values must lie in [0, 1] (``table[255] == 1``). Rounding up keeps every max-grid an upper
    bound of the base: the search stays exact.
    """
    h, w = values.shape
    for iy in range(h):
        for ix in range(w):
            v = values[iy, ix]
            c = min(max(int(math.ceil(v * 255.0)), 0), 255)
            # the product may round either way: settle on the table's own float64 values
            while c > 0 and table[c - 1] >= v:
                c -= 1
            while c < 255 and table[c] < v:
                c += 1
            out[iy, ix] = c


@njit(cache=True)
def max_grids(codes0, h, w, depth, buf, levels, tmp):  # pragma: no cover - compiled
    """Fill the levels ``1 .. depth - 1`` of the flat buffer ``buf`` from the level-0 codes.

    ``codes0`` is the flat (row-major, ``h x w``) code image of the base. A sliding-window
    maximum by doubling (a sparse table): the block of side ``2**lev`` starting at ``(ix, iy)``
    is the union of the four blocks of side ``b = 2**(lev-1)`` starting at ``(ix, iy)``,
    ``(ix + b, iy)``, ``(ix, iy + b)`` and ``(ix + b, iy + b)``, so each level costs two maxima
    per cell of the previous one (rows first, then columns): O(cells) per level. ``tmp`` is a
    uint8 scratch of at least ``(h + 2**(depth-2) - 1) * (w + 2**(depth-1) - 1)`` entries.
    """
    for lev in range(1, depth):
        b = 1 << (lev - 1)
        ps = b - 1  # pad of the source level
        src = codes0 if lev == 1 else buf
        so = 0 if lev == 1 else levels[lev - 1, 0]
        dst = levels[lev, 0]
        hs = h + ps
        ws = w + ps  # >= b, as w >= 1
        wd = ws + b
        # rows: tmp[y, x] = max(source[y, x - b], source[y, x]), a missing one counting 0
        # (stored source column j is grid column j - ps; stored tmp column x is grid x - pd)
        for y in range(hs):
            s0 = so + y * ws
            t0 = y * wd
            _copy(src, s0, tmp, t0, b)
            _max2(src, s0, s0 + b, tmp, t0 + b, ws - b)
            _copy(src, s0 + ws - b, tmp, t0 + ws, b)
        # columns: this level's row y = max(tmp rows y - b and y), a missing one counting 0;
        # rows are contiguous and all wd wide, so each part is one run
        _copy(tmp, 0, buf, dst, b * wd)
        _max2(tmp, 0, b * wd, buf, dst + b * wd, (hs - b) * wd)
        _copy(tmp, (hs - b) * wd, buf, dst + hs * wd, b * wd)


@njit(cache=True, inline="always")
def _copy(src, s0, dst, d0, n):  # pragma: no cover - compiled
    """``dst[d0 : d0 + n] = src[s0 : s0 + n]``."""
    # on slices, indexed from 0: no negative-index wrap to test, so the loops vectorise
    s = src[s0 : s0 + n]
    d = dst[d0 : d0 + n]
    for i in range(n):
        d[i] = s[i]


@njit(cache=True, inline="always")
def _max2(src, a0, b0, dst, d0, n):  # pragma: no cover - compiled
    """``dst[d0 + i] = max(src[a0 + i], src[b0 + i])`` for ``i < n``."""
    sa = src[a0 : a0 + n]
    sb = src[b0 : b0 + n]
    d = dst[d0 : d0 + n]
    for i in range(n):
        a = sa[i]
        c = sb[i]
        d[i] = a if a > c else c


@njit(cache=True)
def cell_tables(pts, x0, y0, th0, step, n_angles, ox, oy, res, cx, cy):  # pragma: no cover
    """Rotate the points once per heading and store their cells seen from ``(x0, y0)``.

    Heading ``a`` is ``th0 + (a - (n_angles - 1) // 2) * step``; ``cx[a, i]``, ``cy[a, i]``
    receive ``floor((x0 + R p_i - origin) / res)``.
    """
    na = (n_angles - 1) // 2
    n = pts.shape[0]
    for a in range(n_angles):
        th = th0 + (a - na) * step
        c = math.cos(th)
        s = math.sin(th)
        for i in range(n):
            px = pts[i, 0]
            py = pts[i, 1]
            cx[a, i] = math.floor((x0 + (c * px - s * py) - ox) / res)
            cy[a, i] = math.floor((y0 + (s * px + c * py) - oy) / res)


@njit(cache=True)
def leaf_sum(base, cxa, cya, kx, ky):  # pragma: no cover - compiled
    """Exact score sum of one candidate: the base values at the points' cells (0 outside)."""
    h, w = base.shape
    total = 0.0
    for i in range(cxa.shape[0]):
        ix = cxa[i] + kx
        iy = cya[i] + ky
        if 0 <= ix < w and 0 <= iy < h:
            total += base[iy, ix]
    return total


@njit(cache=True)
def node_sum(buf, levels, lev, table, cxa, cya, kx, ky):  # pragma: no cover - compiled
    """Upper bound (sum) of every candidate of the node at offset ``(kx, ky)`` of depth ``lev``
    (``levels[lev] = (offset, height, width, pad)`` in ``buf``)."""
    off = levels[lev, 0]
    hp = levels[lev, 1]
    wp = levels[lev, 2]
    pad = levels[lev, 3]
    total = 0.0
    for i in range(cxa.shape[0]):
        j = cya[i] + ky + pad
        k = cxa[i] + kx + pad
        if 0 <= j < hp and 0 <= k < wp:
            total += table[buf[off + j * wp + k]]
    return total


@njit(cache=True)
def root_bounds(buf, levels, table, cx, cy, nl, top, min_score, out):  # pragma: no cover
    """The bound of every root of depth ``top`` (``side = 2**top`` cells), or -1 for a root
    that a bound over its group of headings already puts below ``min_score``; returns the
    scorings done.

    ``out[(a * P + i) * P + j]`` is the root of heading ``a`` at offsets ``(-nl + i side,
    -nl + j side)``, ``P`` roots per axis, as :func:`branch_and_bound` numbers them. Headings
    go in groups of ``side``: over a group each point's cells span a box of corner
    ``(lx, ly)``; when it is at most ``side`` cells wide, the four top-depth entries of the
    blocks at ``(lx + kx, ly + ky)``, ``side`` apart, cover every cell the point reaches from
    any heading of the group and offset of the root, so the largest of them bounds it. A group
    bound (the same sum order, divided by N) below ``min_score`` rules out all the group's roots
    at that offset; the others are scored one by one exactly as :func:`node_sum` does. The
    kept roots and their bounds are those of scoring every root.
    """
    side = 1 << top
    per_axis = (2 * nl) // side + 1
    off = levels[top, 0]
    hp = levels[top, 1]
    wp = levels[top, 2]
    pad = levels[top, 3]
    n_angles = cx.shape[0]
    n = cx.shape[1]
    lx = np.empty(n, dtype=np.int64)
    ly = np.empty(n, dtype=np.int64)
    count = 0
    for a0 in range(0, n_angles, side):
        a1 = min(n_angles, a0 + side)
        grouped = True
        for p in range(n):
            x_lo = cx[a0, p]
            x_hi = x_lo
            y_lo = cy[a0, p]
            y_hi = y_lo
            for a in range(a0 + 1, a1):
                v = cx[a, p]
                x_lo = min(x_lo, v)
                x_hi = max(x_hi, v)
                v = cy[a, p]
                y_lo = min(y_lo, v)
                y_hi = max(y_hi, v)
            if x_hi - x_lo > side or y_hi - y_lo > side:
                grouped = False
            lx[p] = x_lo + pad
            ly[p] = y_lo + pad
        for i in range(per_axis):
            kx = -nl + i * side
            for j in range(per_axis):
                ky = -nl + j * side
                if grouped:
                    total = 0.0
                    for p in range(n):
                        x0 = lx[p] + kx
                        y0 = ly[p] + ky
                        c = 0
                        for dy in range(2):
                            y = y0 + dy * side
                            if 0 <= y < hp:
                                for dx in range(2):
                                    x = x0 + dx * side
                                    if 0 <= x < wp:
                                        c = max(c, buf[off + y * wp + x])
                        total += table[c]
                    count += 1
                    if total / n < min_score:
                        for a in range(a0, a1):
                            out[(a * per_axis + i) * per_axis + j] = -1.0
                        continue
                for a in range(a0, a1):
                    out[(a * per_axis + i) * per_axis + j] = (
                        node_sum(buf, levels, top, table, cx[a], cy[a], kx, ky) / n
                    )
                    count += 1
    return count


@njit(cache=True, inline="always")
def _store(out, found, a, kx, ky, score, count):  # pragma: no cover - compiled
    """``out = (found, a, kx, ky, score, evaluated)``, the result of both searches."""
    out[0] = 1.0 if found else 0.0
    out[1] = a
    out[2] = kx
    out[3] = ky
    out[4] = score
    out[5] = count


@njit(cache=True)
def brute_force(base, cx, cy, nl, min_score, out):  # pragma: no cover - compiled
    """Score every candidate of the window; ``out = (found, a, kx, ky, score, evaluated)``.

    Candidates are visited by heading, then x offset, then y offset, each ascending; the first
    of equal scores wins (the smallest ``(a, kx, ky)``). Scores are means ``sum / N``.
    """
    n = cx.shape[1]
    best, found, ba, bx, by = _NOTHING_FOUND
    count = 0
    for a in range(cx.shape[0]):
        cxa = cx[a]
        cya = cy[a]
        for kx in range(-nl, nl + 1):
            for ky in range(-nl, nl + 1):
                m = leaf_sum(base, cxa, cya, kx, ky) / n
                count += 1
                best, found, ba, bx, by = _keep_best(
                    m, a, kx, ky, min_score, best, found, ba, bx, by
                )
    _store(out, found, ba, bx, by, best, count)


@njit(cache=True)
def _key_less(a1, x1, y1, a2, x2, y2):  # pragma: no cover - compiled
    """Lexicographic ``(a1, x1, y1) < (a2, x2, y2)``."""
    if a1 != a2:
        return a1 < a2
    if x1 != x2:
        return x1 < x2
    return y1 < y2


#: ``(best, found, a, kx, ky)`` before any candidate is scored.
_NOTHING_FOUND = (-math.inf, False, 0, 0, 0)


@njit(cache=True, inline="always")
def _keep_best(m, a, kx, ky, min_score, best, found, ba, bx, by):  # pragma: no cover - compiled
    """The best candidate ``(best, found, ba, bx, by)`` once candidate ``(a, kx, ky)`` scored
    ``m``: the highest score of at least ``min_score``, then the smallest key; the one rule
    of both searches. (Brute force visits keys in ascending order, so for it a tie never
    replaces the best.)"""
    if m >= min_score and (m > best or (m == best and _key_less(a, kx, ky, ba, bx, by))):
        return m, True, a, kx, ky
    return best, found, ba, bx, by


@njit(cache=True)
def branch_and_bound(
    base, buf, levels, table, cx, cy, nl, top, min_score, out
):  # pragma: no cover - compiled
    """Depth-first branch and bound over the window (Hess et al. 2016, sec. V).

    Nodes are ``(a, kx, ky, h)``: heading ``a``, the ``2**h x 2**h`` translation offsets
    starting at ``(kx, ky)`` (clipped to ``[-nl, nl]``). The roots tile the window at depth
    ``top`` for every heading, are scored (with a threshold and ``top >= 2``, by
    :func:`root_bounds`, which rules out whole groups of headings at once), those below
    ``min_score`` dropped and the rest sorted (best first; equal bounds by index); then
    an explicit stack runs the depth-first search, each node's children scored and pushed
    worst first so that the best is expanded next. A node is pruned when its bound is below
    ``min_score`` or below the best score found, or equals it while its smallest key
    ``(a, kx, ky)`` is not smaller than the best's, so the result is the same candidate as
    :func:`brute_force` returns (the highest score, then the smallest key). Depth-1 nodes score
    their (up to four) candidates exactly on the base grid.

    ``out = (found, a, kx, ky, score, evaluated)``, ``evaluated`` counting node and candidate
    scorings.
    """
    n = cx.shape[1]
    n_angles = cx.shape[0]
    side = 1 << top
    per_axis = (2 * nl) // side + 1
    n_roots = n_angles * per_axis * per_axis
    best, found, ba, bx, by = _NOTHING_FOUND
    count = 0

    # roots: every heading at the top depth, scored; those bounded below min_score are
    # dropped at once (the search would prune them), the rest sorted best first
    ra = np.empty(n_roots, dtype=np.int64)
    rx = np.empty(n_roots, dtype=np.int64)
    ry = np.empty(n_roots, dtype=np.int64)
    rs = np.empty(n_roots)
    r = 0
    if top >= 2 and min_score > 0.0:
        # the bounds in place (in rs, by root index), then kept in index order
        count += root_bounds(buf, levels, table, cx, cy, nl, top, min_score, rs)
        pa2 = per_axis * per_axis
        for q in range(n_roots):
            m = rs[q]
            if m < min_score:
                continue
            a = q // pa2
            i = (q - a * pa2) // per_axis
            ra[r] = a
            rx[r] = -nl + i * side
            ry[r] = -nl + (q - a * pa2 - i * per_axis) * side
            rs[r] = m
            r += 1
    else:
        for a in range(n_angles):
            for i in range(per_axis):
                for j in range(per_axis):
                    kx = -nl + i * side
                    ky = -nl + j * side
                    if top == 0:
                        m = leaf_sum(base, cx[a], cy[a], kx, ky) / n
                    else:
                        m = node_sum(buf, levels, top, table, cx[a], cy[a], kx, ky) / n
                    count += 1
                    if m < min_score:
                        continue
                    ra[r] = a
                    rx[r] = kx
                    ry[r] = ky
                    rs[r] = m
                    r += 1
    n_kept = r
    order = np.argsort(-rs[:n_kept], kind="mergesort")  # stable: equal bounds by index

    if top == 0:  # the roots are the candidates
        for q in range(n_kept):
            k = order[q]
            best, found, ba, bx, by = _keep_best(
                rs[k], ra[k], rx[k], ry[k], min_score, best, found, ba, bx, by
            )
        _store(out, found, ba, bx, by, best, count)
        return

    cap = n_kept + 4 * (top + 1)
    sa = np.empty(cap, dtype=np.int64)
    sx = np.empty(cap, dtype=np.int64)
    sy = np.empty(cap, dtype=np.int64)
    sh = np.empty(cap, dtype=np.int64)
    ss = np.empty(cap)
    sp = 0
    for q in range(n_kept - 1, -1, -1):  # worst first: the best is on top of the stack
        k = order[q]
        sa[sp] = ra[k]
        sx[sp] = rx[k]
        sy[sp] = ry[k]
        sh[sp] = top
        ss[sp] = rs[k]
        sp += 1

    cxs = np.empty(4, dtype=np.int64)
    cys = np.empty(4, dtype=np.int64)
    cs = np.empty(4)
    while sp > 0:
        sp -= 1
        a = sa[sp]
        kx0 = sx[sp]
        ky0 = sy[sp]
        h = sh[sp]
        bound = ss[sp]
        # the best may have improved since this node was pushed
        if bound < best or (bound == best and not _key_less(a, kx0, ky0, ba, bx, by)):
            continue
        b = 1 << (h - 1)
        cxa = cx[a]
        cya = cy[a]
        if h == 1:
            # the leaves: exact scores on the base grid, in key order
            for dx in range(2):
                kx = kx0 + dx
                if kx > nl:
                    break
                for dy in range(2):
                    ky = ky0 + dy
                    if ky > nl:
                        break
                    m = leaf_sum(base, cxa, cya, kx, ky) / n
                    count += 1
                    best, found, ba, bx, by = _keep_best(
                        m, a, kx, ky, min_score, best, found, ba, bx, by
                    )
            continue
        # inner node: score the children at depth h - 1, sort them best first
        lev = h - 1
        nc = 0
        for dx in range(2):
            kx = kx0 + dx * b
            if kx > nl:
                break
            for dy in range(2):
                ky = ky0 + dy * b
                if ky > nl:
                    break
                m = node_sum(buf, levels, lev, table, cxa, cya, kx, ky) / n
                count += 1
                # insertion by (bound descending, key ascending)
                p = nc
                while p > 0 and (
                    cs[p - 1] < m
                    or (cs[p - 1] == m and _key_less(a, kx, ky, a, cxs[p - 1], cys[p - 1]))
                ):
                    cs[p] = cs[p - 1]
                    cxs[p] = cxs[p - 1]
                    cys[p] = cys[p - 1]
                    p -= 1
                cs[p] = m
                cxs[p] = kx
                cys[p] = ky
                nc += 1
        for p in range(nc - 1, -1, -1):
            m = cs[p]
            if m < min_score:
                continue
            if m < best or (m == best and not _key_less(a, cxs[p], cys[p], ba, bx, by)):
                continue
            sa[sp] = a
            sx[sp] = cxs[p]
            sy[sp] = cys[p]
            sh[sp] = lev
            ss[sp] = m
            sp += 1
    _store(out, found, ba, bx, by, best, count)
