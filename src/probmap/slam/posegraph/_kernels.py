"""Numba kernels of the SE(2) pose-graph optimizer (private).

Every kernel takes contiguous arrays and scalars; :mod:`probmap.slam.posegraph.optimize` validates inputs
once and owns the sparsity pattern these kernels write into.

Conventions shared by all kernels
---------------------------------
poses : (N, 3) float64
    ``(x, y, theta)`` of every node in the world frame, metres and radians.
ei, ej : (E,) int64
    Node indices of each edge; the measurement is ``x_i^-1 ⊕ x_j``.
meas : (E, 3) float64
    Measured relative pose of ``j`` in ``i``'s frame.
info : (E, 3, 3) float64
    Information matrices (symmetric positive definite).
chart : int
    ``CHART_LOGMAP`` (GTSAM's ``Pose2`` local coordinates, ``Log(m^-1 x_i^-1 x_j)``) or
    ``CHART_XYT`` (g2o and TORO: ``(dx, dy, dtheta)`` of ``m^-1 x_i^-1 x_j``).
kernel, scale, robust : int, float, (E,) bool
    Robust kernel id (``KERNEL_*``), its scale, and which edges it applies to.
graph : tuple
    ``(ei, ej, meas, info, chart, kernel, scale, robust)``: what the cost depends on besides
    the poses, packed once by the caller for the kernels that evaluate or linearize the cost.

Jacobians are taken with respect to ``delta = (R_n xi_t, xi_theta)``: GTSAM's right
perturbation ``x_n Exp(xi_n)`` with its translation rotated into the world frame. The rotation
is orthogonal, so ``lambda * I`` damping and the Gauss-Newton step are GTSAM's; the world-frame
coordinates make ``d t_delta / d t_j`` a plain rotation. :func:`apply_step` is the matching
retraction (``Exp``, as GTSAM's ``Pose2::retract``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from probmap.geometry._kernels import wrap

CHART_LOGMAP = 0
CHART_XYT = 1

KERNEL_NONE = 0
KERNEL_HUBER = 1
KERNEL_CAUCHY = 2
KERNEL_DCS = 3


@njit(cache=True)
def logmap_coeffs(th):  # pragma: no cover - compiled
    """``a(th) = (th/2) cot(th/2)`` and ``da/dth``: ``V(th)^-1 = [[a, th/2], [-th/2, a]]``.

    Taylor series below 1e-2 rad, where the closed form loses digits to cancellation.
    """
    if abs(th) < 1e-2:
        t2 = th * th
        a = 1.0 - t2 / 12.0 - t2 * t2 / 720.0 - t2 * t2 * t2 / 30240.0
        da = -th / 6.0 - th * t2 / 180.0 - th * t2 * t2 / 5040.0
        return a, da
    h = 0.5 * th
    sh = math.sin(h)
    ch = math.cos(h)
    a = h * ch / sh
    da = 0.5 * (ch / sh - h / (sh * sh))
    return a, da


@njit(cache=True, inline="always")
def _edge_delta(poses, i, j, mx, my, mt):  # pragma: no cover - compiled
    """The parts of one edge's residual that both :func:`edge_residual` and
    :func:`edge_linearize` start from: ``u = R_i^T (t_j - t_i)`` (``ux, uy``), ``u - t_m``
    rotated into the measurement frame (``tx, ty``), the wrapped heading error ``th`` and
    ``cos``/``sin`` of the measured heading (``cm, sm``)."""
    ci = math.cos(poses[i, 2])
    si = math.sin(poses[i, 2])
    dx = poses[j, 0] - poses[i, 0]
    dy = poses[j, 1] - poses[i, 1]
    ux = ci * dx + si * dy
    uy = -si * dx + ci * dy
    # z = R_i^T (t_j - t_i) - t_m, then rotated into the measurement frame
    zx = ux - mx
    zy = uy - my
    cm = math.cos(mt)
    sm = math.sin(mt)
    tx = cm * zx + sm * zy
    ty = -sm * zx + cm * zy
    th = wrap(poses[j, 2] - poses[i, 2] - mt)
    return ux, uy, tx, ty, th, cm, sm


@njit(cache=True)
def edge_residual(poses, i, j, mx, my, mt, chart, e):  # pragma: no cover - compiled
    """Residual ``e (3,)`` of one edge (written in place)."""
    _, _, tx, ty, th, _, _ = _edge_delta(poses, i, j, mx, my, mt)
    if chart == CHART_LOGMAP:
        a, _ = logmap_coeffs(th)
        b = 0.5 * th
        e[0] = a * tx + b * ty
        e[1] = -b * tx + a * ty
    else:
        e[0] = tx
        e[1] = ty
    e[2] = th


@njit(cache=True)
def edge_linearize(poses, i, j, mx, my, mt, chart, e, A, B):  # pragma: no cover - compiled
    """Residual ``e (3,)`` and Jacobians ``A = de/dx_i``, ``B = de/dx_j`` (3, 3), in place."""
    ux, uy, tx, ty, th, cm, sm = _edge_delta(poses, i, j, mx, my, mt)
    # R_im^T = (R_i R_m)^T: d t_delta / d t_j (and minus d / d t_i)
    cim = math.cos(poses[i, 2] + mt)
    sim = math.sin(poses[i, 2] + mt)
    r00 = cim
    r01 = sim
    r10 = -sim
    r11 = cim
    # d t_delta / d theta_i = R_m^T (u_y, -u_x)
    gx = cm * uy - sm * ux
    gy = -sm * uy - cm * ux
    if chart == CHART_LOGMAP:
        a, da = logmap_coeffs(th)
        b = 0.5 * th
        e[0] = a * tx + b * ty
        e[1] = -b * tx + a * ty
        # M = V^-1 = [[a, b], [-b, a]]; dM/dth = [[da, 1/2], [-1/2, da]]
        m00 = a
        m01 = b
        m10 = -b
        m11 = a
        hx = da * tx + 0.5 * ty
        hy = -0.5 * tx + da * ty
    else:
        e[0] = tx
        e[1] = ty
        m00 = 1.0
        m01 = 0.0
        m10 = 0.0
        m11 = 1.0
        hx = 0.0
        hy = 0.0
    e[2] = th
    # translation rows: M R_im^T for t_j, -M R_im^T for t_i
    p00 = m00 * r00 + m01 * r10
    p01 = m00 * r01 + m01 * r11
    p10 = m10 * r00 + m11 * r10
    p11 = m10 * r01 + m11 * r11
    B[0, 0] = p00
    B[0, 1] = p01
    B[1, 0] = p10
    B[1, 1] = p11
    B[0, 2] = hx
    B[1, 2] = hy
    B[2, 0] = 0.0
    B[2, 1] = 0.0
    B[2, 2] = 1.0
    A[0, 0] = -p00
    A[0, 1] = -p01
    A[1, 0] = -p10
    A[1, 1] = -p11
    A[0, 2] = m00 * gx + m01 * gy - hx
    A[1, 2] = m10 * gx + m11 * gy - hy
    A[2, 0] = 0.0
    A[2, 1] = 0.0
    A[2, 2] = -1.0


@njit(cache=True)
def rho_weight(s, kernel, scale):  # pragma: no cover - compiled
    """Robust cost ``rho(s)`` of a squared Mahalanobis distance ``s`` and its IRLS weight
    ``w = d rho / d s``. ``rho(s) = s`` without a kernel, so ``0.5 * rho`` is GTSAM's error.

    Huber and Cauchy take ``scale`` in Mahalanobis-distance units (sqrt of ``s``); DCS takes
    ``Phi = scale`` in ``s`` units (Agarwal et al. 2013: ``w = min(1, 2 Phi / (Phi + s))^2``,
    whose integral is ``rho = 3 Phi - 4 Phi^2 / (Phi + s)`` above ``Phi``).
    """
    if kernel == KERNEL_NONE:
        return s, 1.0
    if kernel == KERNEL_HUBER:
        d = math.sqrt(s)
        if d <= scale:
            return s, 1.0
        return 2.0 * scale * d - scale * scale, scale / d
    if kernel == KERNEL_CAUCHY:
        k2 = scale * scale
        return k2 * math.log1p(s / k2), 1.0 / (1.0 + s / k2)
    # KERNEL_DCS
    if s <= scale:
        return s, 1.0
    q = scale + s
    return 3.0 * scale - 4.0 * scale * scale / q, 4.0 * scale * scale / (q * q)


@njit(cache=True)
def mahalanobis(e, info, k):  # pragma: no cover - compiled
    """``e' info[k] e``."""
    s = 0.0
    for r in range(3):
        for c in range(3):
            s += e[r] * info[k, r, c] * e[c]
    return s


@njit(cache=True, inline="always")
def _edge_rho_weight(s, robust, kernel, scale):  # pragma: no cover - compiled
    """:func:`rho_weight` for an edge under the robust kernel, ``(s, 1)`` for a plain one."""
    if robust:
        return rho_weight(s, kernel, scale)
    return s, 1.0


@njit(cache=True)
def graph_cost(poses, graph, chi2, weights):  # pragma: no cover - compiled
    """Total cost ``0.5 * sum rho(e' Omega e)``; per-edge ``chi2`` and IRLS ``weights`` in place."""
    ei, ej, meas, info, chart, kernel, scale, robust = graph
    e = np.empty(3)
    total = 0.0
    for k in range(ei.shape[0]):
        edge_residual(poses, ei[k], ej[k], meas[k, 0], meas[k, 1], meas[k, 2], chart, e)
        s = mahalanobis(e, info, k)
        chi2[k] = s
        r, w = _edge_rho_weight(s, robust[k], kernel, scale)
        weights[k] = w
        total += r
    return 0.5 * total


@njit(cache=True)
def _add_block(data, colptr, col0, base, M, upper_only):  # pragma: no cover - compiled
    """``data`` += the 3x3 block ``M`` whose rows start at entry ``base`` of each of the three
    scalar columns ``col0 .. col0 + 2`` (only the upper triangle for a diagonal block)."""
    for c in range(3):
        p = colptr[col0 + c] + base
        if upper_only:
            for r in range(c + 1):
                data[p + r] += M[r, c]
        else:
            for r in range(3):
                data[p + r] += M[r, c]


@njit(cache=True, inline="always")
def _transposed_product(X, Y, M):  # pragma: no cover - compiled
    """``M = X' Y`` for 3x3 ``X``, ``Y`` (sums in the order ``m = 0, 1, 2``)."""
    for r0 in range(3):
        for c0 in range(3):
            acc = 0.0
            for m in range(3):
                acc += X[m, r0] * Y[m, c0]
            M[r0, c0] = acc


@njit(cache=True, inline="always")
def _add_transposed_product(X, v, out, base):  # pragma: no cover - compiled
    """``out[base:base + 3] += X' v`` for 3x3 ``X`` and 3-vector ``v``."""
    for r0 in range(3):
        acc = 0.0
        for m in range(3):
            acc += X[m, r0] * v[m]
        out[base + r0] += acc


@njit(cache=True)
def accumulate_normal_equations(
    poses, graph, node_index, colptr, diag_base, edge_base, data, rhs
):  # pragma: no cover - compiled
    """Gauss-Newton system ``H = sum w J' Omega J`` (upper triangle, CSC ``data``) and
    ``rhs = sum w J' Omega e`` (the gradient); returns the cost ``0.5 * sum rho``.

    ``node_index[n]`` is the block row/column of node ``n`` (-1 when held fixed).
    ``diag_base[c]`` and ``edge_base[k]`` are the offsets, inside each scalar column of block
    column ``c`` (``max`` of the edge's two blocks), of the diagonal block and of edge ``k``'s
    off-diagonal block.
    """
    ei, ej, meas, info, chart, kernel, scale, robust = graph
    data[:] = 0.0
    rhs[:] = 0.0
    e = np.empty(3)
    A = np.empty((3, 3))
    B = np.empty((3, 3))
    WA = np.empty((3, 3))
    WB = np.empty((3, 3))
    M = np.empty((3, 3))
    We = np.empty(3)
    total = 0.0
    for k in range(ei.shape[0]):
        i = ei[k]
        j = ej[k]
        edge_linearize(poses, i, j, meas[k, 0], meas[k, 1], meas[k, 2], chart, e, A, B)
        s = mahalanobis(e, info, k)
        r, w = _edge_rho_weight(s, robust[k], kernel, scale)
        total += r
        p = node_index[i]
        q = node_index[j]
        # W = w * Omega; WA = W A, WB = W B, We = W e
        for r0 in range(3):
            acc = 0.0
            for c0 in range(3):
                wrc = w * info[k, r0, c0]
                acc += wrc * e[c0]
            We[r0] = acc
            for c0 in range(3):
                sa = 0.0
                sb = 0.0
                for m in range(3):
                    wrm = w * info[k, r0, m]
                    sa += wrm * A[m, c0]
                    sb += wrm * B[m, c0]
                WA[r0, c0] = sa
                WB[r0, c0] = sb
        if p >= 0:  # gradient J_i' W e and diagonal block A' W A
            _add_transposed_product(A, We, rhs, 3 * p)
            _transposed_product(A, WA, M)
            _add_block(data, colptr, 3 * p, diag_base[p], M, True)
        if q >= 0:  # gradient J_j' W e and diagonal block B' W B
            _add_transposed_product(B, We, rhs, 3 * q)
            _transposed_product(B, WB, M)
            _add_block(data, colptr, 3 * q, diag_base[q], M, True)
        if p >= 0 and q >= 0 and p != q:
            if p < q:  # block (p, q) = A' W B
                _transposed_product(A, WB, M)
                _add_block(data, colptr, 3 * q, edge_base[k], M, False)
            else:  # block (q, p) = B' W A
                _transposed_product(B, WA, M)
                _add_block(data, colptr, 3 * p, edge_base[k], M, False)
    return 0.5 * total


@njit(cache=True)
def number_free_nodes(n_nodes, fixed):  # pragma: no cover - compiled
    """``node_index`` (-1 for the ``fixed`` nodes, the others numbered in order) and the
    number of free nodes."""
    node_index = np.zeros(n_nodes, dtype=np.int64)
    for f in fixed:
        node_index[f] = -1
    nf = 0
    for v in range(n_nodes):
        if node_index[v] == 0:
            node_index[v] = nf
            nf += 1
    return node_index, nf


@njit(cache=True)
def build_structure(ei, ej, node_index):  # pragma: no cover - compiled
    """The upper-triangular CSC pattern of ``H`` in 3x3 blocks of the free nodes.

    ``node_index[n]`` is the block (elimination position) of node ``n``, -1 when it is fixed.
    Returns ``(colptr, indices, diag_base, edge_base, diag_pos, blk_colptr, blk_rows)``: in
    every scalar column of block column ``c`` the off-diagonal blocks come first, by
    increasing block row, then the diagonal block's upper triangle; ``diag_base[c]`` and
    ``edge_base[k]`` are the offsets, inside each scalar column of the block's column, of the
    diagonal block and of edge ``k``'s off-diagonal block (-1 when an end is fixed; parallel
    edges share a block); ``diag_pos`` the positions of the diagonal entries in ``data``;
    ``blk_rows[blk_colptr[c]:blk_colptr[c + 1]]`` the off-diagonal block rows of column ``c``.
    """
    nf = 0
    for v in range(node_index.shape[0]):
        if node_index[v] >= 0:
            nf += 1
    E = ei.shape[0]
    keys = np.empty(E, dtype=np.int64)
    which = np.empty(E, dtype=np.int64)
    m = 0
    for k in range(E):
        p = node_index[ei[k]]
        q = node_index[ej[k]]
        if p >= 0 and q >= 0:
            keys[m] = max(p, q) * nf + min(p, q)
            which[m] = k
            m += 1
    order = np.argsort(keys[:m])
    edge_block = np.full(E, -1, dtype=np.int64)
    ucol = np.empty(m, dtype=np.int64)
    urow = np.empty(m, dtype=np.int64)
    n_blocks = 0
    last = -1
    for t in range(m):
        key = keys[order[t]]
        if key != last:
            ucol[n_blocks] = key // nf
            urow[n_blocks] = key % nf
            n_blocks += 1
            last = key
        edge_block[which[order[t]]] = n_blocks - 1
    nb = np.zeros(nf, dtype=np.int64)
    for b in range(n_blocks):
        nb[ucol[b]] += 1
    blk_colptr = np.zeros(nf + 1, dtype=np.int64)
    for c in range(nf):
        blk_colptr[c + 1] = blk_colptr[c] + nb[c]
    colptr = np.zeros(3 * nf + 1, dtype=np.int64)
    for c in range(nf):
        for k in range(3):
            colptr[3 * c + k + 1] = colptr[3 * c + k] + 3 * nb[c] + k + 1
    indices = np.empty(colptr[3 * nf], dtype=np.int64)
    diag_pos = np.empty(3 * nf, dtype=np.int64)
    for c in range(nf):
        for k in range(3):
            p = colptr[3 * c + k]
            for b in range(blk_colptr[c], blk_colptr[c + 1]):
                r = urow[b]
                indices[p] = 3 * r
                indices[p + 1] = 3 * r + 1
                indices[p + 2] = 3 * r + 2
                p += 3
            for r in range(k + 1):
                indices[p] = 3 * c + r
                p += 1
            diag_pos[3 * c + k] = colptr[3 * c + k] + 3 * nb[c] + k
    edge_base = np.full(E, -1, dtype=np.int64)
    for k in range(E):
        b = edge_block[k]
        if b >= 0:
            edge_base[k] = 3 * (b - blk_colptr[ucol[b]])
    return colptr, indices, 3 * nb, edge_base, diag_pos, blk_colptr, urow[:n_blocks].copy()


@njit(cache=True)
def apply_step(poses, node_index, delta, out):  # pragma: no cover - compiled
    """Retraction ``out_n = x_n Exp(xi_n)`` of the free nodes (fixed nodes copied).

    ``delta[3p:3p+3] = (R_n xi_t, xi_theta)`` is the increment with its translation rotated
    into the world frame, the coordinates of the Jacobians of :func:`edge_linearize`; since
    planar rotations commute, ``x_n Exp(xi_n)`` moves the translation by ``V(xi_theta)`` times
    that world-frame translation, ``V(w) = [[sin w / w, -(1 - cos w) / w], [(1 - cos w) / w,
    sin w / w]]``. Angles are wrapped to ``[-pi, pi)``.
    """
    for n in range(poses.shape[0]):
        p = node_index[n]
        if p < 0:
            out[n, 0] = poses[n, 0]
            out[n, 1] = poses[n, 1]
            out[n, 2] = poses[n, 2]
        else:
            dx = delta[3 * p]
            dy = delta[3 * p + 1]
            w = delta[3 * p + 2]
            if abs(w) < 1e-6:
                a = 1.0 - w * w / 6.0
                b = 0.5 * w
            else:
                a = math.sin(w) / w
                b = (1.0 - math.cos(w)) / w
            out[n, 0] = poses[n, 0] + a * dx - b * dy
            out[n, 1] = poses[n, 1] + b * dx + a * dy
            out[n, 2] = wrap(poses[n, 2] + w)


@njit(cache=True)
def edge_residuals(poses, ei, ej, meas, chart, out):  # pragma: no cover - compiled
    """Residual of every edge into ``out (E, 3)``."""
    e = np.empty(3)
    for k in range(ei.shape[0]):
        edge_residual(poses, ei[k], ej[k], meas[k, 0], meas[k, 1], meas[k, 2], chart, e)
        out[k, 0] = e[0]
        out[k, 1] = e[1]
        out[k, 2] = e[2]


@njit(cache=True)
def check_edges(ei, ej, n_nodes, meas):  # pragma: no cover - compiled
    """First edge with a node index outside ``[0, n_nodes)`` (code 1), joining a node to
    itself (2) or with a non-finite measurement (3), as ``(k, code)``; ``(-1, 0)`` if none."""
    for k in range(ei.shape[0]):
        if ei[k] < 0 or ei[k] >= n_nodes or ej[k] < 0 or ej[k] >= n_nodes:
            return k, 1
        if ei[k] == ej[k]:
            return k, 2
        for c in range(3):
            if not math.isfinite(meas[k, c]):
                return k, 3
    return -1, 0


@njit(cache=True)
def check_information(info, rtol):  # pragma: no cover - compiled
    """First edge whose information matrix is not finite (code 1), not symmetric (2) or not
    positive semi-definite (3), as ``(k, code)``; ``(-1, 0)`` when all are fine.

    Positive semi-definite: every principal minor ``>= -rtol * scale^order`` (Sylvester's
    criterion for semi-definiteness needs all of them, not only the leading ones), ``scale``
    the largest absolute entry.
    """
    for k in range(info.shape[0]):
        M = info[k]
        scale = 0.0
        for r in range(3):
            for c in range(3):
                v = M[r, c]
                if not math.isfinite(v):
                    return k, 1
                scale = max(scale, abs(v))
        if scale == 0.0:
            continue
        for r in range(3):
            for c in range(r + 1, 3):
                if abs(M[r, c] - M[c, r]) > rtol * scale:
                    return k, 2
        t1 = -rtol * scale
        t2 = -rtol * scale * scale
        t3 = -rtol * scale * scale * scale
        if M[0, 0] < t1 or M[1, 1] < t1 or M[2, 2] < t1:
            return k, 3
        m01 = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
        m02 = M[0, 0] * M[2, 2] - M[0, 2] * M[2, 0]
        m12 = M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1]
        if m01 < t2 or m02 < t2 or m12 < t2:
            return k, 3
        det = (
            M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1])
            - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
            + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0])
        )
        if det < t3:
            return k, 3
    return -1, 0


@njit(cache=True)
def spanning_tree(n_nodes, ei, ej, dtheta, fixed, theta):  # pragma: no cover - compiled
    """Breadth-first spanning forest rooted at the ``fixed`` nodes; headings along it.

    ``theta[f]`` of the fixed nodes is read; every node the search reaches gets
    ``theta[parent] +- dtheta[k]`` (``+`` when its tree edge ``k`` points away from the parent;
    not wrapped). Unreached nodes (not connected to a fixed node) get NaN. Returns how many
    nodes were reached.
    """
    E = ei.shape[0]
    # undirected adjacency in CSR form (counting sort of the edge ends)
    start = np.zeros(n_nodes + 1, dtype=np.int64)
    for k in range(E):
        start[ei[k] + 1] += 1
        start[ej[k] + 1] += 1
    for v in range(n_nodes):
        start[v + 1] += start[v]
    fill = start[:-1].copy()
    nbr = np.empty(2 * E, dtype=np.int64)
    for k in range(E):
        nbr[fill[ei[k]]] = k
        fill[ei[k]] += 1
        nbr[fill[ej[k]]] = k
        fill[ej[k]] += 1
    seen = np.zeros(n_nodes, dtype=np.bool_)
    queue = np.empty(n_nodes, dtype=np.int64)
    head = 0
    tail = 0
    for f in fixed:
        if not seen[f]:
            seen[f] = True
            queue[tail] = f
            tail += 1
    while head < tail:
        u = queue[head]
        head += 1
        for t in range(start[u], start[u + 1]):
            k = nbr[t]
            if ei[k] == u:
                v = ej[k]
                d = dtheta[k]
            else:
                v = ei[k]
                d = -dtheta[k]
            if not seen[v]:
                seen[v] = True
                theta[v] = theta[u] + d
                queue[tail] = v
                tail += 1
    for v in range(n_nodes):
        if not seen[v]:
            theta[v] = np.nan
    return tail


@njit(cache=True)
def _add_laplacian_block(
    data, rhs, colptr, diag_base, edge_base, k, p, q, M, g, lo, dim
):  # pragma: no cover - compiled
    """Add the edge term ``|u_q - u_p - r|^2_M`` of a linear least-squares problem on the
    ``dim`` coordinates starting at ``lo`` of each node's 3-block: ``M`` to the diagonal blocks,
    ``-M`` to the off-diagonal one, ``-g`` and ``+g`` (``g = M r``) to the right-hand side."""
    for c in range(dim):
        if p >= 0:
            rhs[3 * p + lo + c] -= g[c]
        if q >= 0:
            rhs[3 * q + lo + c] += g[c]
        for r in range(dim):
            if r <= c:  # the upper triangle of the diagonal blocks
                if p >= 0:
                    data[colptr[3 * p + lo + c] + diag_base[p] + lo + r] += M[r, c]
                if q >= 0:
                    data[colptr[3 * q + lo + c] + diag_base[q] + lo + r] += M[r, c]
            if p >= 0 and q >= 0:
                col = max(p, q)
                data[colptr[3 * col + lo + c] + edge_base[k] + lo + r] -= M[r, c]


@njit(cache=True)
def assemble_lago(
    stage, poses, theta, ei, ej, meas, info, node_index, colptr, diag_base, edge_base, data, rhs
):  # pragma: no cover - compiled
    """Normal equations of LAGO's two linear stages in the optimizer's block pattern.

    ``stage == 0`` (headings): unknown ``phi = theta - theta_tree`` with ``theta`` the tree
    headings; each edge adds ``w (phi_j - phi_i - r)^2`` with ``r = z_theta + 2 pi l -
    (theta_j - theta_i)``, ``l`` the integer that brings the tree's heading difference closest
    to ``z_theta``, and ``w = 1 / Sigma_theta_theta`` (the heading's marginal information;
    ``Omega_theta_theta`` when the translational block is singular).
    ``stage == 1`` (positions): unknown the correction of ``poses[:, :2]``; each edge adds
    ``|d - (t_j - t_i)|^2_W`` with ``d = R(theta_i) z_t`` and ``W = R(theta_i) Omega_tt
    R(theta_i)'``.
    The coordinates a stage does not solve for get a unit diagonal and a zero right-hand
    side, so their solution is 0.
    """
    data[:] = 0.0
    rhs[:] = 0.0
    M = np.zeros((2, 2))
    g = np.zeros(2)
    two_pi = 2.0 * math.pi
    for k in range(ei.shape[0]):
        i = ei[k]
        j = ej[k]
        p = node_index[i]
        q = node_index[j]
        O = info[k]
        if stage == 0:
            m2 = O[0, 0] * O[1, 1] - O[0, 1] * O[1, 0]
            w = O[2, 2]
            if m2 > 1e-12 * (O[0, 0] * O[1, 1] + 1e-300):
                det = (
                    O[0, 0] * (O[1, 1] * O[2, 2] - O[1, 2] * O[2, 1])
                    - O[0, 1] * (O[1, 0] * O[2, 2] - O[1, 2] * O[2, 0])
                    + O[0, 2] * (O[1, 0] * O[2, 1] - O[1, 1] * O[2, 0])
                )
                w = det / m2
            diff = theta[j] - theta[i]
            ell = math.floor((diff - meas[k, 2]) / two_pi + 0.5)
            r = meas[k, 2] + two_pi * ell - diff
            M[0, 0] = w
            g[0] = w * r
            _add_laplacian_block(data, rhs, colptr, diag_base, edge_base, k, p, q, M, g, 2, 1)
        else:
            c = math.cos(theta[i])
            s = math.sin(theta[i])
            dx = c * meas[k, 0] - s * meas[k, 1] - (poses[j, 0] - poses[i, 0])
            dy = s * meas[k, 0] + c * meas[k, 1] - (poses[j, 1] - poses[i, 1])
            # W = R O_tt R'
            a00 = O[0, 0]
            a01 = 0.5 * (O[0, 1] + O[1, 0])
            a11 = O[1, 1]
            M[0, 0] = c * c * a00 - 2.0 * c * s * a01 + s * s * a11
            M[1, 1] = s * s * a00 + 2.0 * c * s * a01 + c * c * a11
            M[0, 1] = c * s * (a00 - a11) + (c * c - s * s) * a01
            M[1, 0] = M[0, 1]
            g[0] = M[0, 0] * dx + M[0, 1] * dy
            g[1] = M[1, 0] * dx + M[1, 1] * dy
            _add_laplacian_block(data, rhs, colptr, diag_base, edge_base, k, p, q, M, g, 0, 2)
    # unit diagonal for the coordinates this stage does not solve
    lo = 0 if stage == 0 else 2
    hi = 2 if stage == 0 else 3
    for p in range(diag_base.shape[0]):
        for c in range(lo, hi):
            data[colptr[3 * p + c] + diag_base[p] + c] = 1.0


# ----------------------------------------------------------------------------- block LDL'
# H = L D L' with L unit lower block-triangular and D block diagonal (3x3 blocks), computed row
# by row as in QDLDL (Stellato, Goulart, Banjac; after Davis's LDL, "Algorithm 849", ACM TOMS
# 2005), on 3x3 blocks: one index per 27 multiply-adds. The elimination tree and the column
# counts of L come once per sparsity pattern; each factorization is numeric only. The block
# ordering (fill-reducing) is the caller's: it numbers the blocks.

STATUS_CAP = 0
STATUS_RELATIVE = 1
STATUS_ABSOLUTE = 2
STATUS_NO_DECREASE = 3
STATUS_NOTHING = 4
STATUS_ZERO = 5


@njit(cache=True)
def ldl_symbolic(blk_colptr, blk_rows):  # pragma: no cover - compiled
    """Elimination tree ``etree (n,)`` (-1 at roots) and column pointers ``Lp (n + 1,)`` of the
    strictly lower block triangle of ``L``, from the upper block pattern of ``H``."""
    n = blk_colptr.shape[0] - 1
    etree = np.full(n, -1, dtype=np.int64)
    work = np.full(n, -1, dtype=np.int64)
    Lnz = np.zeros(n, dtype=np.int64)
    for j in range(n):
        work[j] = j
        for p in range(blk_colptr[j], blk_colptr[j + 1]):
            i = blk_rows[p]
            while work[i] != j:
                if etree[i] == -1:
                    etree[i] = j
                Lnz[i] += 1
                work[i] = j
                i = etree[i]
    Lp = np.zeros(n + 1, dtype=np.int64)
    for j in range(n):
        Lp[j + 1] = Lp[j] + Lnz[j]
    return etree, Lp


@njit(cache=True)
def _inverse_spd3(M, out):  # pragma: no cover - compiled
    """``out = M^-1`` for a symmetric 3x3 ``M`` by Cholesky; False if ``M`` is not positive
    definite (to working precision)."""
    a = M[0, 0]
    if not a > 0.0:
        return False
    l00 = math.sqrt(a)
    l10 = M[1, 0] / l00
    l20 = M[2, 0] / l00
    b = M[1, 1] - l10 * l10
    if not b > 1e-14 * M[1, 1]:
        return False
    l11 = math.sqrt(b)
    l21 = (M[2, 1] - l20 * l10) / l11
    c = M[2, 2] - l20 * l20 - l21 * l21
    if not c > 1e-14 * M[2, 2]:
        return False
    l22 = math.sqrt(c)
    # inverse of L (lower), then M^-1 = L^-T L^-1
    i00 = 1.0 / l00
    i11 = 1.0 / l11
    i22 = 1.0 / l22
    i10 = -l10 * i00 * i11
    i21 = -l21 * i11 * i22
    i20 = -(l20 * i00 + l21 * i10) * i22
    out[0, 0] = i00 * i00 + i10 * i10 + i20 * i20
    out[1, 1] = i11 * i11 + i21 * i21
    out[2, 2] = i22 * i22
    out[0, 1] = out[1, 0] = i10 * i11 + i20 * i21
    out[0, 2] = out[2, 0] = i20 * i22
    out[1, 2] = out[2, 1] = i21 * i22
    return True


@njit(cache=True)
def ldl_storage(Lp, n):  # pragma: no cover - compiled
    """``Li``, ``Lx`` and ``Dinv`` for :func:`ldl_factor` of ``n`` blocks with the column
    pointers ``Lp`` of :func:`ldl_symbolic` (one allocation, reused by every factorization)."""
    return np.empty(Lp[n], dtype=np.int64), np.empty((Lp[n], 3, 3)), np.empty((n, 3, 3))


@njit(cache=True)
def ldl_factor(
    data, colptr, diag_base, blk_colptr, blk_rows, etree, Lp, lam, damp, Li, Lx, Dinv
):  # pragma: no cover - compiled
    """Numeric ``L D L'`` of ``H + lam * diag(damp)``, ``H`` given by its upper-triangle CSC
    ``data`` (the optimizer's pattern). Writes ``Li``, ``Lx (nnz, 3, 3)`` and ``Dinv (n, 3, 3)``;
    returns False when a pivot block is not positive definite."""
    n = blk_colptr.shape[0] - 1
    nxt = Lp[:-1].copy()
    marker = np.zeros(n, dtype=np.bool_)
    y = np.zeros((n, 3, 3))
    y_idx = np.empty(n, dtype=np.int64)
    buf = np.empty(n, dtype=np.int64)
    Dk = np.empty((3, 3))
    for k in range(n):
        # D_k = H_kk (+ damping), symmetric from the stored upper triangle
        base = diag_base[k]
        for c in range(3):
            p0 = colptr[3 * k + c] + base
            for r in range(c + 1):
                Dk[r, c] = data[p0 + r]
                Dk[c, r] = data[p0 + r]
            Dk[c, c] += lam * damp[3 * k + c]
        # y = H[0:k, k] scattered, and the rows it reaches in the elimination tree
        n_y = 0
        for t in range(blk_colptr[k], blk_colptr[k + 1]):
            i = blk_rows[t]
            off = 3 * (t - blk_colptr[k])
            for c in range(3):
                p0 = colptr[3 * k + c] + off
                for r in range(3):
                    y[i, r, c] = data[p0 + r]
            if not marker[i]:
                marker[i] = True
                buf[0] = i
                n_e = 1
                j = etree[i]
                while j != -1 and j < k:
                    if marker[j]:
                        break
                    marker[j] = True
                    buf[n_e] = j
                    n_e += 1
                    j = etree[j]
                while n_e > 0:
                    n_e -= 1
                    y_idx[n_y] = buf[n_e]
                    n_y += 1
        # eliminate in topological order: y_c is final when reached
        for t in range(n_y - 1, -1, -1):
            cidx = y_idx[t]
            Y = y[cidx]
            for q in range(Lp[cidx], nxt[cidx]):
                r = Li[q]
                L = Lx[q]
                for a in range(3):
                    for b in range(3):
                        y[r, a, b] -= L[a, 0] * Y[0, b] + L[a, 1] * Y[1, b] + L[a, 2] * Y[2, b]
            q = nxt[cidx]
            Li[q] = k
            Dc = Dinv[cidx]
            for a in range(3):  # L_kc = Y' Dinv_c
                for b in range(3):
                    Lx[q, a, b] = Y[0, a] * Dc[0, b] + Y[1, a] * Dc[1, b] + Y[2, a] * Dc[2, b]
            for a in range(3):  # D_k -= L_kc Y
                for b in range(3):
                    Dk[a, b] -= (
                        Lx[q, a, 0] * Y[0, b] + Lx[q, a, 1] * Y[1, b] + Lx[q, a, 2] * Y[2, b]
                    )
            nxt[cidx] += 1
            y[cidx] = 0.0
            marker[cidx] = False
        if not _inverse_spd3(Dk, Dinv[k]):
            return False
    return True


@njit(cache=True)
def ldl_solve(Lp, Li, Lx, Dinv, b, x):  # pragma: no cover - compiled
    """``x = (L D L')^-1 b`` with the factors of :func:`ldl_factor` (``b``, ``x`` of length 3n)."""
    n = Lp.shape[0] - 1
    x[:] = b
    for i in range(n):  # L z = b
        for q in range(Lp[i], Lp[i + 1]):
            r = Li[q]
            for a in range(3):
                x[3 * r + a] -= (
                    Lx[q, a, 0] * x[3 * i] + Lx[q, a, 1] * x[3 * i + 1] + Lx[q, a, 2] * x[3 * i + 2]
                )
    t = np.empty(3)
    for i in range(n):  # D w = z
        for a in range(3):
            t[a] = (
                Dinv[i, a, 0] * x[3 * i]
                + Dinv[i, a, 1] * x[3 * i + 1]
                + Dinv[i, a, 2] * x[3 * i + 2]
            )
        x[3 * i] = t[0]
        x[3 * i + 1] = t[1]
        x[3 * i + 2] = t[2]
    for i in range(n - 1, -1, -1):  # L' x = w
        for q in range(Lp[i], Lp[i + 1]):
            r = Li[q]
            for a in range(3):
                x[3 * i + a] -= (
                    Lx[q, 0, a] * x[3 * r] + Lx[q, 1, a] * x[3 * r + 1] + Lx[q, 2, a] * x[3 * r + 2]
                )


# ----------------------------------------------------------------------------- LM and LAGO


@njit(cache=True)
def levenberg_marquardt(
    poses,
    graph,
    node_index,
    colptr,
    diag_base,
    edge_base,
    blk_colptr,
    blk_rows,
    etree,
    Lp,
    max_iterations,
    relative_tolerance,
    absolute_tolerance,
    initial_lambda,
    max_lambda,
    identity_damping,
    out,
    chi2,
    weights,
):  # pragma: no cover - compiled
    """Levenberg-Marquardt (Madsen, Nielsen and Tingleff 2004, 3.2) with Nielsen's damping
    update: linearize, factor ``H + lambda D`` (``D = I`` or ``diag(H)``), step by the
    retraction, accept if the cost falls (then lower lambda by the gain ratio) or raise lambda
    and refactor. ``out`` receives the poses; returns ``(cost, iterations, status)``, status
    one of ``STATUS_*``; ``chi2`` and ``weights`` are those of the final poses."""  # fmt: skip
    n = blk_colptr.shape[0] - 1
    n3 = 3 * n
    data = np.empty(colptr[n3])
    rhs = np.empty(n3)
    neg = np.empty(n3)
    delta = np.empty(n3)
    damp = np.ones(n3)
    Li, Lx, Dinv = ldl_storage(Lp, n)
    x = poses.copy()
    x_try = poses.copy()
    F = accumulate_normal_equations(x, graph, node_index, colptr, diag_base, edge_base, data, rhs)
    iterations = 0
    status = STATUS_CAP
    if n3 == 0 or chi2.shape[0] == 0:  # no free node or no edge
        status = STATUS_NOTHING
    elif F == 0.0:
        status = STATUS_ZERO
    lam = -1.0
    nu = 2.0
    F_try = F
    while status == STATUS_CAP and iterations < max_iterations:
        iterations += 1
        dmax = 0.0
        for p in range(n):
            for c in range(3):
                dmax = max(dmax, data[colptr[3 * p + c] + diag_base[p] + c])
        if not identity_damping:
            for p in range(n):
                for c in range(3):
                    damp[3 * p + c] = max(data[colptr[3 * p + c] + diag_base[p] + c], 1e-12 * dmax)
        # Levenberg's lambda is relative to the largest curvature, Marquardt's to each one's own
        unit = dmax if identity_damping else 1.0
        if lam < 0.0:
            lam = initial_lambda * unit
        lam_cap = max_lambda * unit
        for a in range(n3):
            neg[a] = -rhs[a]
        accepted = False
        gain = 0.0
        while True:
            if ldl_factor(
                data, colptr, diag_base, blk_colptr, blk_rows, etree, Lp, lam, damp, Li, Lx, Dinv
            ):
                ldl_solve(Lp, Li, Lx, Dinv, neg, delta)
                apply_step(x, node_index, delta, x_try)
                F_try = graph_cost(x_try, graph, chi2, weights)
                gain = F - F_try
                if math.isfinite(F_try) and gain > 0.0:
                    # gain ratio against the model's predicted decrease (Madsen et al. 3.14)
                    dd = 0.0
                    db = 0.0
                    for a in range(n3):
                        dd += delta[a] * damp[a] * delta[a]
                        db += delta[a] * rhs[a]
                    predicted = 0.5 * (lam * dd - db)
                    rho = gain / predicted if predicted > 0.0 else 1.0
                    lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                    nu = 2.0
                    accepted = True
                    break
            lam *= nu
            nu *= 2.0
            if lam > lam_cap:
                break
        if not accepted:
            status = STATUS_NO_DECREASE
            break
        x[:, :] = x_try
        F_prev = F
        F = F_try
        if gain <= relative_tolerance * F_prev:
            status = STATUS_RELATIVE
        elif gain <= absolute_tolerance:
            status = STATUS_ABSOLUTE
        elif iterations < max_iterations:
            accumulate_normal_equations(
                x, graph, node_index, colptr, diag_base, edge_base, data, rhs
            )
    out[:, :] = x
    F = graph_cost(x, graph, chi2, weights)
    return F, iterations, status


@njit(cache=True)
def _add_ridge(data, diag_pos, lo, hi):  # pragma: no cover - compiled
    """Add 1e-10 of the largest of the diagonal entries ``lo..hi-1`` of every block to them."""
    top = 1e-300
    for t in range(0, diag_pos.shape[0], 3):
        for c in range(lo, hi):
            top = max(top, data[diag_pos[t + c]])
    for t in range(0, diag_pos.shape[0], 3):
        for c in range(lo, hi):
            data[diag_pos[t + c]] += 1e-10 * top


@njit(cache=True)
def lago(
    poses,
    ei,
    ej,
    meas,
    info,
    fixed,
    node_index,
    colptr,
    diag_base,
    edge_base,
    diag_pos,
    blk_colptr,
    blk_rows,
    etree,
    Lp,
    rerounds,
    out,
):  # pragma: no cover - compiled
    """Linear approximation of the pose graph (LAGO; Carlone, Aragues, Castellanos and Bona,
    IJRR 2014) in the optimizer's block pattern; ``out`` receives the poses. Returns False if
    a linear system was not positive definite.

    1. Headings along a breadth-first spanning tree rooted at the fixed nodes.
    2. All headings by linear least squares, the multiples of 2 pi from the tree's headings;
       then again with the multiples rounded from the estimate, until the headings settle
       (at most ``rerounds`` times; the matrix is the same).
    3. All positions by linear least squares given the headings.
    A ridge of 1e-10 of the largest curvature keeps nodes with too little information
    solvable (they stay where they were).
    """  # fmt: skip
    N = poses.shape[0]
    n = blk_colptr.shape[0] - 1
    n3 = 3 * n
    theta = poses[:, 2].copy()
    spanning_tree(N, ei, ej, np.ascontiguousarray(meas[:, 2]), fixed, theta)
    out[:, :] = poses
    if n > 0:
        data = np.empty(colptr[n3])
        rhs = np.empty(n3)
        u = np.empty(n3)
        zero = np.zeros(n3)
        Li, Lx, Dinv = ldl_storage(Lp, n)
        pattern = (node_index, colptr, diag_base, edge_base)
        assemble_lago(0, out, theta, ei, ej, meas, info, *pattern, data, rhs)
        _add_ridge(data, diag_pos, 2, 3)
        if not ldl_factor(
            data, colptr, diag_base, blk_colptr, blk_rows, etree, Lp, 0.0, zero, Li, Lx, Dinv
        ):
            return False
        for r in range(rerounds + 1):
            if r > 0:
                assemble_lago(0, out, theta, ei, ej, meas, info, *pattern, np.empty_like(data), rhs)
            ldl_solve(Lp, Li, Lx, Dinv, rhs, u)
            step = 0.0
            for v in range(N):
                p = node_index[v]
                if p >= 0:
                    theta[v] += u[3 * p + 2]
                    step = max(step, abs(u[3 * p + 2]))
            if r > 0 and step < 1e-9:
                break
        assemble_lago(1, out, theta, ei, ej, meas, info, *pattern, data, rhs)
        _add_ridge(data, diag_pos, 0, 2)
        if not ldl_factor(
            data, colptr, diag_base, blk_colptr, blk_rows, etree, Lp, 0.0, zero, Li, Lx, Dinv
        ):
            return False
        ldl_solve(Lp, Li, Lx, Dinv, rhs, u)
        for v in range(N):
            p = node_index[v]
            if p >= 0:
                out[v, 0] += u[3 * p]
                out[v, 1] += u[3 * p + 1]
    for v in range(N):
        out[v, 2] = wrap(theta[v])
    for f in fixed:
        out[f, 0] = poses[f, 0]
        out[f, 1] = poses[f, 1]
        out[f, 2] = poses[f, 2]
    return True
