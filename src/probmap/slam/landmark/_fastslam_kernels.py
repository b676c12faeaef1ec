"""Numba kernels of FastSLAM's shared landmark tree (private).

Montemerlo's balanced binary tree (Probabilistic Robotics section 13.8, "Efficient
Implementation"): every particle's landmark filters hang at the leaves of a binary tree of
depth ``D``; particles share subtrees, so that resampling copies a root (``O(1)`` per particle)
and changing one landmark copies only the ``D + 1`` nodes on its path (copy-on-write).

:mod:`probmap.slam.landmark.fastslam` owns the node pool and validates its inputs; these kernels only
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

from probmap.geometry._kernels import wrap
from probmap.slam.landmark._kernels import gemm, range_bearing

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


@njit(cache=True, inline="always")
def _find_leaf(child, root, c, depth):  # pragma: no cover - compiled
    """The node holding column ``c`` under ``root`` (0 where the path ends before it)."""
    x = root
    level = depth - 1
    while x != 0 and level >= 0:
        x = child[x, (c >> level) & 1]
        level -= 1
    return x


@njit(cache=True, inline="always")
def _copy_gaussian(dst_mean, dst_cov, src_mean, src_cov):  # pragma: no cover - compiled
    """Copy one landmark filter: mean (2,) and covariance (2, 2)."""
    dst_mean[0] = src_mean[0]
    dst_mean[1] = src_mean[1]
    for i in range(2):
        for j in range(2):
            dst_cov[i, j] = src_cov[i, j]


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
        x = _find_leaf(child, roots[m], c, depth)
        if x == 0:
            continue
        out_found[m] = True
        _copy_gaussian(out_mean[m], out_cov[m], mean[x], cov[x])
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
                _copy_gaussian(mean[y], cov[y], mean[x], cov[x])
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
        _copy_gaussian(mean[leaf], cov[leaf], new_mean[m], new_cov[m])
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
        if _find_leaf(child, roots[m], c, depth) == 0:
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
                    _copy_gaussian(out_mean[m, c], out_cov[m, c], mean[x], cov[x])
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
            zb[n] = wrap(math.atan2(dy, dx) - heading)
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
                e1 = wrap(z[i, 1] - zb[n])
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


@njit(cache=True)
def _logpdf2(e0, e1, s00, s01, s10, s11):  # pragma: no cover - compiled
    det = s00 * s11 - s01 * s10
    m = (s11 * e0 * e0 - (s01 + s10) * e0 * e1 + s00 * e1 * e1) / det
    return -0.5 * m - 0.5 * math.log(det) - math.log(_TWO_PI)


@njit(cache=True)
def fastslam_update(
    particles, predicted, Rt, v2, z, R, offset, cols, mode, mean, cov, count, noise, new_logw,
    logw,
):  # pragma: no cover - compiled  # fmt: skip
    """One measurement step of FastSLAM for every particle (Tables 13.1 and 13.3).

    ``z (k, 2)``: the step's observations; ``cols (k, M)``: the column of observation ``i`` in
    particle ``m``; ``mode (k, M)``: 0 nothing, 1 a landmark the particle holds, 2 a new one;
    ``mean (k, M, 2)``, ``cov (k, M, 2, 2)``, ``count (k, M)``: the landmark of each (read as
    gathered, rewritten with the update). With ``v2`` the pose is first drawn from the
    proposal built from ``predicted (M, 3)``, ``Rt (3, 3)`` and the mode-1 observations, as
    ``x + chol(Sigma) noise[m]`` (``noise (M, 3)`` standard normal); ``particles (M, 3)`` is
    overwritten with the draw. Adds each particle's log importance factor to ``logw (M,)``
    (``new_logw`` for a new landmark). An observation of a column seen earlier in the step
    updates that earlier result (a landmark is never initialized twice).
    """
    k = z.shape[0]
    n_part = particles.shape[0]
    # scratch of the small block products, allocated once before the loop over particles
    hm = np.empty((2, 2))
    hx = np.empty((2, 3))
    P = np.empty((3, 3))
    x = np.empty(3)
    pht = np.empty((3, 2))
    kg = np.empty((3, 2))
    for m in range(n_part):
        if v2:
            # Table 13.3 lines 6-14: the proposal, one observation after the other
            for a in range(3):
                x[a] = predicted[m, a]
                for b in range(3):
                    P[a, b] = Rt[a, b] + (1e-12 if a == b else 0.0)
            for i in range(k):
                if mode[i, m] != 1:
                    continue
                zr, zb = range_bearing(
                    x[0], x[1], x[2], offset, mean[i, m, 0], mean[i, m, 1], hm, hx
                )
                C = cov[i, m]
                # S = H_m C H_m' + R
                s = np.empty((2, 2))
                for a in range(2):
                    for b in range(2):
                        acc = R[a, b]
                        for u in range(2):
                            for v in range(2):
                                acc += hm[a, u] * C[u, v] * hm[b, v]
                        s[a, b] = acc
                e0 = z[i, 0] - zr
                e1 = wrap(z[i, 1] - zb)
                pht[:] = 0.0
                gemm(P, hx.T, 1.0, pht)
                t00 = s[0, 0]
                t01 = s[0, 1]
                t10 = s[1, 0]
                t11 = s[1, 1]
                for u in range(3):
                    t00 += hx[0, u] * pht[u, 0]
                    t01 += hx[0, u] * pht[u, 1]
                    t10 += hx[1, u] * pht[u, 0]
                    t11 += hx[1, u] * pht[u, 1]
                det = t00 * t11 - t01 * t10
                i00 = t11 / det
                i01 = -t01 / det
                i10 = -t10 / det
                i11 = t00 / det
                for a in range(3):
                    kg[a, 0] = pht[a, 0] * i00 + pht[a, 1] * i10
                    kg[a, 1] = pht[a, 0] * i01 + pht[a, 1] * i11
                for a in range(3):
                    x[a] += kg[a, 0] * e0 + kg[a, 1] * e1
                x[2] = wrap(x[2])
                for a in range(3):
                    for b in range(3):
                        P[a, b] -= kg[a, 0] * pht[b, 0] + kg[a, 1] * pht[b, 1]
            # symmetrize, Cholesky (3 x 3), draw
            for a in range(3):
                for b in range(a):
                    v = 0.5 * (P[a, b] + P[b, a])
                    P[a, b] = v
                    P[b, a] = v
                P[a, a] += 1e-15
            l00 = math.sqrt(P[0, 0])
            l10 = P[1, 0] / l00
            l20 = P[2, 0] / l00
            l11 = math.sqrt(P[1, 1] - l10 * l10)
            l21 = (P[2, 1] - l20 * l10) / l11
            l22 = math.sqrt(P[2, 2] - l20 * l20 - l21 * l21)
            particles[m, 0] = x[0] + l00 * noise[m, 0]
            particles[m, 1] = x[1] + l10 * noise[m, 0] + l11 * noise[m, 1]
            particles[m, 2] = wrap(x[2] + l20 * noise[m, 0] + l21 * noise[m, 1] + l22 * noise[m, 2])
        px = particles[m, 0]
        py = particles[m, 1]
        pth = particles[m, 2]
        for i in range(k):
            md = mode[i, m]
            if md == 0:
                continue
            for j in range(i - 1, -1, -1):  # the same landmark earlier in the step
                if mode[j, m] != 0 and cols[j, m] == cols[i, m]:
                    mean[i, m, 0] = mean[j, m, 0]
                    mean[i, m, 1] = mean[j, m, 1]
                    for a in range(2):
                        for b in range(2):
                            cov[i, m, a, b] = cov[j, m, a, b]
                    count[i, m] = count[j, m]
                    md = 1
                    break
            if md == 2:
                # Table 13.1 lines 10-12: initialize from the inverse measurement model
                c = math.cos(pth)
                s_ = math.sin(pth)
                sx = px + c * offset[0] - s_ * offset[1]
                sy = py + s_ * offset[0] + c * offset[1]
                ang = pth + offset[2] + z[i, 1]
                ca = math.cos(ang)
                sa = math.sin(ang)
                mean[i, m, 0] = sx + z[i, 0] * ca
                mean[i, m, 1] = sy + z[i, 0] * sa
                j00 = ca
                j01 = -z[i, 0] * sa
                j10 = sa
                j11 = z[i, 0] * ca
                a00 = j00 * R[0, 0] + j01 * R[1, 0]
                a01 = j00 * R[0, 1] + j01 * R[1, 1]
                a10 = j10 * R[0, 0] + j11 * R[1, 0]
                a11 = j10 * R[0, 1] + j11 * R[1, 1]
                cov[i, m, 0, 0] = a00 * j00 + a01 * j01
                cov[i, m, 0, 1] = a00 * j10 + a01 * j11
                cov[i, m, 1, 0] = a10 * j00 + a11 * j01
                cov[i, m, 1, 1] = a10 * j10 + a11 * j11
                count[i, m] = 1
                logw[m] += new_logw
                continue
            # Table 13.1 lines 14-18: the landmark's EKF update
            mu0 = mean[i, m, 0]
            mu1 = mean[i, m, 1]
            zr, zb = range_bearing(px, py, pth, offset, mu0, mu1, hm, hx)
            C = cov[i, m].copy()
            hc = np.empty((2, 2))  # H_m C
            for a in range(2):
                for b in range(2):
                    hc[a, b] = hm[a, 0] * C[0, b] + hm[a, 1] * C[1, b]
            q00 = R[0, 0] + hc[0, 0] * hm[0, 0] + hc[0, 1] * hm[0, 1]
            q01 = R[0, 1] + hc[0, 0] * hm[1, 0] + hc[0, 1] * hm[1, 1]
            q10 = R[1, 0] + hc[1, 0] * hm[0, 0] + hc[1, 1] * hm[0, 1]
            q11 = R[1, 1] + hc[1, 0] * hm[1, 0] + hc[1, 1] * hm[1, 1]
            det = q00 * q11 - q01 * q10
            i00 = q11 / det
            i01 = -q01 / det
            i10 = -q10 / det
            i11 = q00 / det
            e0 = z[i, 0] - zr
            e1 = wrap(z[i, 1] - zb)
            # K = C H_m' Q^-1 = (H_m C)' Q^-1
            k00 = hc[0, 0] * i00 + hc[1, 0] * i10
            k01 = hc[0, 0] * i01 + hc[1, 0] * i11
            k10 = hc[0, 1] * i00 + hc[1, 1] * i10
            k11 = hc[0, 1] * i01 + hc[1, 1] * i11
            mean[i, m, 0] = mu0 + k00 * e0 + k01 * e1
            mean[i, m, 1] = mu1 + k10 * e0 + k11 * e1
            n00 = C[0, 0] - (k00 * hc[0, 0] + k01 * hc[1, 0])
            n01 = C[0, 1] - (k00 * hc[0, 1] + k01 * hc[1, 1])
            n10 = C[1, 0] - (k10 * hc[0, 0] + k11 * hc[1, 0])
            n11 = C[1, 1] - (k10 * hc[0, 1] + k11 * hc[1, 1])
            cov[i, m, 0, 0] = n00
            cov[i, m, 1, 1] = n11
            cov[i, m, 0, 1] = 0.5 * (n01 + n10)
            cov[i, m, 1, 0] = 0.5 * (n01 + n10)
            count[i, m] += 1
            if v2:
                # Table 13.3 line 16: the likelihood under the proposal's prior
                pm = predicted[m]
                pr, pb = range_bearing(pm[0], pm[1], pm[2], offset, mu0, mu1, hm, hx)
                f0 = z[i, 0] - pr
                f1 = wrap(z[i, 1] - pb)
                l00_ = q00
                l01_ = q01
                l10_ = q10
                l11_ = q11
                for u in range(3):
                    for v in range(3):
                        l00_ += hx[0, u] * Rt[u, v] * hx[0, v]
                        l01_ += hx[0, u] * Rt[u, v] * hx[1, v]
                        l10_ += hx[1, u] * Rt[u, v] * hx[0, v]
                        l11_ += hx[1, u] * Rt[u, v] * hx[1, v]
                logw[m] += _logpdf2(f0, f1, l00_, l01_, l10_, l11_)
            else:
                logw[m] += _logpdf2(e0, e1, q00, q01, q10, q11)
