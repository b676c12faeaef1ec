"""Numba kernels of FastSLAM's shared landmark tree (private).

Montemerlo's balanced binary tree (Probabilistic Robotics section 13.8, "Efficient
Implementation"): every particle's landmark filters hang at the leaves of a binary tree of
depth ``D``; particles share subtrees, so that resampling copies a root (``O(1)`` per particle)
and changing one landmark copies only the ``D + 1`` nodes on its path (copy-on-write).

:mod:`probmap.slam.fastslam` owns the node pool and validates its inputs; these kernels only
walk and rewrite it.

Conventions
-----------
child : (cap, 2) int64
    Children of each node (left: bit 0, right: bit 1 of the column index, most significant bit
    first). Node ``0`` is the shared empty subtree: a path that reaches it holds no landmark.
refc : (cap,) int64
    How many parents (or particle roots) point at each node; a node whose count falls to 0
    returns to the free stack, and its children lose one reference.
mean, cov, count : (cap, 2), (cap, 2, 2), (cap,) float64 / int64
    The leaf payload: the landmark's EKF and its evidence counter (Table 13.2's ``i``).
free : (cap,) int64, and ``top`` : (1,) int64
    Stack of free nodes, ``free[:top[0]]``. The caller reserves enough free nodes before each
    call that allocates (at most ``M (D + 1)`` for a path per particle).
copied : (1,) int64
    Counter of nodes allocated by path copying (for tests and diagnostics).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_TWO_PI = 2.0 * math.pi


@njit(cache=True)
def _alloc(free, top):  # pragma: no cover - compiled
    top[0] -= 1
    return free[top[0]]


@njit(cache=True)
def tree_release(child, refc, free, top, nodes):  # pragma: no cover - compiled
    """Drop one reference to each of ``nodes`` (int64, 0 entries skipped); nodes left with
    none go back to the free stack, and so on down their subtrees."""
    stack = np.empty(64 * (nodes.shape[0] + 1), dtype=np.int64)
    for i in range(nodes.shape[0]):
        if nodes[i] == 0:
            continue
        n = 1
        stack[0] = nodes[i]
        while n > 0:
            n -= 1
            x = stack[n]
            refc[x] -= 1
            if refc[x] == 0:
                free[top[0]] = x
                top[0] += 1
                for b in range(2):
                    c = child[x, b]
                    if c != 0:
                        if n >= stack.shape[0]:
                            bigger = np.empty(2 * stack.shape[0], dtype=np.int64)
                            bigger[:n] = stack[:n]
                            stack = bigger
                        stack[n] = c
                        n += 1
                child[x, 0] = 0
                child[x, 1] = 0


@njit(cache=True)
def tree_incref(refc, nodes):  # pragma: no cover - compiled
    """Add one reference to each of ``nodes`` (0 entries skipped)."""
    for i in range(nodes.shape[0]):
        if nodes[i] != 0:
            refc[nodes[i]] += 1


@njit(cache=True)
def tree_gather(
    child, mean, cov, count, roots, cols, depth, out_mean, out_cov, out_count, out_found
):  # pragma: no cover - compiled
    """Read column ``cols[m]`` of particle ``m``'s tree (``cols[m] < 0``: nothing) into the
    ``out_*`` rows; ``out_found[m]`` says whether the particle holds that landmark."""
    for m in range(roots.shape[0]):
        c = cols[m]
        out_found[m] = False
        if c < 0:
            continue
        x = roots[m]
        level = depth - 1
        while x != 0 and level >= 0:
            x = child[x, (c >> level) & 1]
            level -= 1
        if x == 0:
            continue
        out_found[m] = True
        out_mean[m, 0] = mean[x, 0]
        out_mean[m, 1] = mean[x, 1]
        for i in range(2):
            for j in range(2):
                out_cov[m, i, j] = cov[x, i, j]
        out_count[m] = count[x]


@njit(cache=True)
def _writable_path(
    child, refc, mean, cov, count, free, top, roots, m, c, depth, copied
):  # pragma: no cover - compiled
    """The leaf of column ``c`` in particle ``m``'s tree, made exclusive to the particle:
    shared nodes on the path (reference count above 1) and empty ones are copied or created,
    exclusive ones are reused in place. Returns the leaf and its parent (-1 at depth 0)."""
    parent = -1
    bit = 0
    x = roots[m]
    for level in range(depth, -1, -1):
        if x == 0 or refc[x] > 1:
            y = _alloc(free, top)
            copied[0] += 1
            refc[y] = 1
            if x == 0:
                child[y, 0] = 0
                child[y, 1] = 0
                mean[y, 0] = 0.0
                mean[y, 1] = 0.0
                for i in range(2):
                    for j in range(2):
                        cov[y, i, j] = 0.0
                count[y] = 0
            else:
                for b in range(2):
                    child[y, b] = child[x, b]
                    if child[x, b] != 0:
                        refc[child[x, b]] += 1
                mean[y, 0] = mean[x, 0]
                mean[y, 1] = mean[x, 1]
                for i in range(2):
                    for j in range(2):
                        cov[y, i, j] = cov[x, i, j]
                count[y] = count[x]
                refc[x] -= 1  # the copy replaces it on this path (still held elsewhere)
            if parent < 0:
                roots[m] = y
            else:
                child[parent, bit] = y
            x = y
        if level == 0:
            return x, parent
        parent = x
        bit = (c >> (level - 1)) & 1
        x = child[x, bit]
    return x, parent


@njit(cache=True)
def tree_scatter(
    child, refc, mean, cov, count, free, top, roots, cols, depth, new_mean, new_cov, new_count,
    copied,
):  # pragma: no cover - compiled  # fmt: skip
    """Write row ``m`` of ``new_*`` as column ``cols[m]`` of particle ``m``'s tree (``cols[m]
    < 0``: untouched), copying the shared nodes of the path first."""
    for m in range(roots.shape[0]):
        c = cols[m]
        if c < 0:
            continue
        leaf, _ = _writable_path(child, refc, mean, cov, count, free, top, roots, m, c, depth,
                                 copied)  # fmt: skip
        mean[leaf, 0] = new_mean[m, 0]
        mean[leaf, 1] = new_mean[m, 1]
        for i in range(2):
            for j in range(2):
                cov[leaf, i, j] = new_cov[m, i, j]
        count[leaf] = new_count[m]


@njit(cache=True)
def tree_clear(
    child, refc, mean, cov, count, free, top, roots, cols, depth, copied
):  # pragma: no cover - compiled
    """Remove column ``cols[m]`` from particle ``m``'s tree (``cols[m] < 0``: untouched)."""
    one = np.empty(1, dtype=np.int64)
    for m in range(roots.shape[0]):
        c = cols[m]
        if c < 0:
            continue
        # nothing to do where the landmark is absent (avoids copying a path to an empty leaf)
        x = roots[m]
        level = depth - 1
        while x != 0 and level >= 0:
            x = child[x, (c >> level) & 1]
            level -= 1
        if x == 0:
            continue
        leaf, parent = _writable_path(child, refc, mean, cov, count, free, top, roots, m, c,
                                      depth, copied)  # fmt: skip
        one[0] = leaf
        if parent < 0:
            roots[m] = 0
        else:
            child[parent, c & 1] = 0
        tree_release(child, refc, free, top, one)


@njit(cache=True)
def tree_dense(
    child, mean, cov, count, roots, depth, out_mean, out_cov, out_count, out_found
):  # pragma: no cover - compiled
    """Every particle's landmarks as dense rows: column ``c`` of particle ``m`` in
    ``out_*[m, c]`` (``out_found`` False where absent, and for columns past the tree's)."""
    n_cols = out_found.shape[1]
    node_stack = np.empty(depth + 2, dtype=np.int64)
    col_stack = np.empty(depth + 2, dtype=np.int64)
    lev_stack = np.empty(depth + 2, dtype=np.int64)
    for m in range(roots.shape[0]):
        for c in range(n_cols):
            out_found[m, c] = False
        if roots[m] == 0:
            continue
        n = 1
        node_stack[0] = roots[m]
        col_stack[0] = 0
        lev_stack[0] = depth
        while n > 0:
            n -= 1
            x = node_stack[n]
            c = col_stack[n]
            lev = lev_stack[n]
            if lev == 0:
                if c < n_cols:
                    out_found[m, c] = True
                    out_mean[m, c, 0] = mean[x, 0]
                    out_mean[m, c, 1] = mean[x, 1]
                    for i in range(2):
                        for j in range(2):
                            out_cov[m, c, i, j] = cov[x, i, j]
                    out_count[m, c] = count[x]
                continue
            for b in range(1, -1, -1):
                y = child[x, b]
                if y != 0:
                    node_stack[n] = y
                    col_stack[n] = 2 * c + b
                    lev_stack[n] = lev - 1
                    n += 1


@njit(cache=True)
def tree_grow(child, refc, free, top, roots):  # pragma: no cover - compiled
    """One level deeper: each non-empty root becomes the left child of a new root (particles
    that shared a root share the new one); the columns keep their leaves."""
    for m in range(roots.shape[0]):
        r = roots[m]
        if r == 0:
            continue
        shared = -1
        for k in range(m):  # an earlier particle with the same old root already grew it
            if roots[k] != 0 and child[roots[k], 0] == r:
                shared = roots[k]
                break
        if shared >= 0:
            refc[shared] += 1
            refc[r] -= 1
            roots[m] = shared
            continue
        y = _alloc(free, top)
        child[y, 0] = r
        child[y, 1] = 0
        refc[y] = 1
        roots[m] = y


@njit(cache=True)
def _wrap(a):  # pragma: no cover - compiled
    return a - _TWO_PI * math.floor((a + math.pi) / _TWO_PI)


@njit(cache=True)
def associate_ml(
    poses, offset, mean, cov, found, z, R, Rt, use_rt, log_p0, vis_range, vis_half_fov, cols,
    unseen,
):  # pragma: no cover - compiled  # fmt: skip
    """Maximum-likelihood association per particle (Table 13.2 lines 5-15).

    Particle ``m`` at ``poses[m] (3,)`` (sensor at ``offset (3,)`` in the robot frame) holds
    landmark ``n`` where ``found[m, n]``, with mean ``mean[m, n] (2,)`` and covariance
    ``cov[m, n] (2, 2)``. Observation ``z[i] = (range m, bearing rad)`` goes to the landmark
    of largest ``log N(z_i; h(x, mu), H_m Sigma H_m' + R [+ H_x Rt H_x'])`` not taken by an
    earlier observation of the step: ``cols[i, m]`` is its column, or ``-1`` (a new landmark)
    when that log-likelihood is below ``log_p0``. ``unseen[m, n]``: held, not matched, and
    predicted within ``vis_range`` and ``vis_half_fov`` of the sensor heading.
    """
    n_part, n_lm = found.shape
    k = z.shape[0]
    zr = np.empty(n_lm)
    zb = np.empty(n_lm)
    i00 = np.empty(n_lm)
    i01 = np.empty(n_lm)
    i11 = np.empty(n_lm)
    norm = np.empty(n_lm)
    free = np.empty(n_lm, dtype=np.bool_)
    log2pi = math.log(_TWO_PI)
    for m in range(n_part):
        th = poses[m, 2]
        c = math.cos(th)
        s = math.sin(th)
        sx = poses[m, 0] + c * offset[0] - s * offset[1]
        sy = poses[m, 1] + s * offset[0] + c * offset[1]
        dsx = -s * offset[0] - c * offset[1]
        dsy = c * offset[0] - s * offset[1]
        heading = th + offset[2]
        for n in range(n_lm):
            free[n] = found[m, n]
            if not found[m, n]:
                continue
            dx = mean[m, n, 0] - sx
            dy = mean[m, n, 1] - sy
            q = max(dx * dx + dy * dy, 1e-18)
            r = math.sqrt(q)
            zr[n] = r
            zb[n] = _wrap(math.atan2(dy, dx) - heading)
            h00 = dx / r
            h01 = dy / r
            h10 = -dy / q
            h11 = dx / q
            # S = H_m Sigma H_m' + R
            a00 = cov[m, n, 0, 0] * h00 + cov[m, n, 0, 1] * h01
            a01 = cov[m, n, 0, 0] * h10 + cov[m, n, 0, 1] * h11
            a10 = cov[m, n, 1, 0] * h00 + cov[m, n, 1, 1] * h01
            a11 = cov[m, n, 1, 0] * h10 + cov[m, n, 1, 1] * h11
            s00 = h00 * a00 + h01 * a10 + R[0, 0]
            s01 = h00 * a01 + h01 * a11 + R[0, 1]
            s10 = h10 * a00 + h11 * a10 + R[1, 0]
            s11 = h10 * a01 + h11 * a11 + R[1, 1]
            if use_rt:
                # H_x = [-H_m, -H_m ds - (0, 1)']
                x0 = -h00
                x1 = -h01
                x2 = -(h00 * dsx + h01 * dsy)
                y0 = -h10
                y1 = -h11
                y2 = -(h10 * dsx + h11 * dsy) - 1.0
                b0 = Rt[0, 0] * x0 + Rt[0, 1] * x1 + Rt[0, 2] * x2
                b1 = Rt[1, 0] * x0 + Rt[1, 1] * x1 + Rt[1, 2] * x2
                b2 = Rt[2, 0] * x0 + Rt[2, 1] * x1 + Rt[2, 2] * x2
                e0 = Rt[0, 0] * y0 + Rt[0, 1] * y1 + Rt[0, 2] * y2
                e1 = Rt[1, 0] * y0 + Rt[1, 1] * y1 + Rt[1, 2] * y2
                e2 = Rt[2, 0] * y0 + Rt[2, 1] * y1 + Rt[2, 2] * y2
                s00 += x0 * b0 + x1 * b1 + x2 * b2
                s01 += x0 * e0 + x1 * e1 + x2 * e2
                s10 += y0 * b0 + y1 * b1 + y2 * b2
                s11 += y0 * e0 + y1 * e1 + y2 * e2
            det = s00 * s11 - s01 * s10
            i00[n] = s11 / det
            i01[n] = -0.5 * (s01 + s10) / det
            i11[n] = s00 / det
            norm[n] = -0.5 * math.log(det) - log2pi
        for i in range(k):
            best = -1
            best_ll = -np.inf
            for n in range(n_lm):
                if not free[n]:
                    continue
                e0 = z[i, 0] - zr[n]
                e1 = _wrap(z[i, 1] - zb[n])
                ll = norm[n] - 0.5 * (i00[n] * e0 * e0 + 2.0 * i01[n] * e0 * e1 + i11[n] * e1 * e1)
                if ll > best_ll:
                    best_ll = ll
                    best = n
            if best >= 0 and best_ll >= log_p0:
                cols[i, m] = best
                free[best] = False
            else:
                cols[i, m] = -1
        for n in range(n_lm):
            unseen[m, n] = free[n] and zr[n] <= vis_range and abs(zb[n]) <= vis_half_fov
