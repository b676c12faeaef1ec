"""Numba kernels of landmark GraphSLAM (private): the odometry chain and the step smoother.

:mod:`probmap.slam.landmark.graphslam` validates inputs and owns the factor graph; these kernels
only run the motion model along the steps of a log, which is the one part of GraphSLAM that walks
every odometry record (60,000 on an MRCLAM robot) at every linearization.

Conventions
-----------
kind, params : int, (7,) float64
    The motion model: ``KIND_VELOCITY`` with ``(a1, a2, a3, a4, sigma_v, sigma_w, ref_dt)``
    (:class:`probmap.models.motion.VelocityModel`) or ``KIND_ACKERMANN`` with
    ``(L, H, a, b, sigma_v, sigma_steer, ref_dt)`` (:class:`~probmap.models.motion.AckermannModel`);
    ``ref_dt < 0`` stands for ``reference_dt=None``. The arithmetic is that of the models'
    ``predict`` and ``control_covariance`` (checked against them in the tests).
seg_ptr : (S + 1,) int64
    Segment ``s`` (from node ``s`` to node ``s + 1``) is made of steps
    ``seg_ptr[s] .. seg_ptr[s + 1] - 1``; the last of them ends at node ``s + 1``.
floor : (3,) float64
    Variance per second added to every step's process noise (keeps it invertible).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from probmap.geometry._kernels import wrap
from probmap.models._motion_kernels import ackermann_rates
from probmap.slam.landmark._kernels import ZERO_RANGE, gemm, range_bearing

KIND_VELOCITY = 0
KIND_ACKERMANN = 1

STATUS_OK = 0
STATUS_SINGULAR_STEERING = 1
STATUS_SINGULAR_NOISE = 2

_SERIES = 1e-4


@njit(cache=True)
def _arc_terms(d):  # pragma: no cover - compiled
    if abs(d) < _SERIES:
        d2 = d * d
        return 1.0 - d2 / 6.0, d / 2.0 - d * d2 / 24.0, -d / 3.0, 0.5 - d2 / 8.0
    s = math.sin(d)
    c = math.cos(d)
    return s / d, (1.0 - c) / d, (d * c - s) / (d * d), (d * s - (1.0 - c)) / (d * d)


@njit(cache=True)
def model_step(kind, p, x, u0, u1, dt, xn, G, Q):  # pragma: no cover - compiled
    """One motion step from pose ``x``: ``xn = g(u, x)``, ``G = dg/dx``, ``Q = V M V^T``.

    Returns a status (``STATUS_OK`` or ``STATUS_SINGULAR_STEERING``).
    """
    V00 = V01 = V10 = V11 = V20 = V21 = 0.0
    M0 = 0.0
    M1 = 0.0
    th = x[2]
    c = math.cos(th)
    s = math.sin(th)
    for r in range(3):
        for k in range(3):
            G[r, k] = 1.0 if r == k else 0.0
    if kind == KIND_VELOCITY:
        v = u0
        w = u1
        d = w * dt
        A, B, dA, dB = _arc_terms(d)
        px = c * A - s * B
        py = s * A + c * B
        xn[0] = x[0] + v * dt * px
        xn[1] = x[1] + v * dt * py
        xn[2] = wrap(th + d)
        G[0, 2] = -v * dt * py
        G[1, 2] = v * dt * px
        V00 = dt * px
        V10 = dt * py
        V01 = v * dt * dt * (c * dA - s * dB)
        V11 = v * dt * dt * (s * dA + c * dB)
        V21 = dt
        v2 = v * v
        w2 = w * w
        M0 = p[0] * v2 + p[1] * w2 + p[4] * p[4]
        M1 = p[2] * v2 + p[3] * w2 + p[5] * p[5]
    else:
        ve = u0
        al = u1
        L = p[0]
        H = p[1]
        a = p[2]
        b = p[3]
        ok, vc, k, dvc_dve, dvc_dal, dk_dve, dk_dal = ackermann_rates(ve, math.tan(al), H, L)
        if not ok:
            return STATUS_SINGULAR_STEERING
        ox = a * s + b * c
        oy = a * c - b * s
        xn[0] = x[0] + dt * (vc * c - k * ox)
        xn[1] = x[1] + dt * (vc * s + k * oy)
        xn[2] = wrap(th + dt * k)
        G[0, 2] = dt * (-vc * s - k * oy)
        G[1, 2] = dt * (vc * c - k * ox)
        V00 = dt * (dvc_dve * c - dk_dve * ox)
        V01 = dt * (dvc_dal * c - dk_dal * ox)
        V10 = dt * (dvc_dve * s + dk_dve * oy)
        V11 = dt * (dvc_dal * s + dk_dal * oy)
        V20 = dt * dk_dve
        V21 = dt * dk_dal
        M0 = p[4] * p[4]
        M1 = p[5] * p[5]
    if p[6] > 0.0 and dt > 0.0:
        M0 *= p[6] / dt
        M1 *= p[6] / dt
    Q[0, 0] = V00 * M0 * V00 + V01 * M1 * V01
    Q[0, 1] = V00 * M0 * V10 + V01 * M1 * V11
    Q[0, 2] = V00 * M0 * V20 + V01 * M1 * V21
    Q[1, 1] = V10 * M0 * V10 + V11 * M1 * V11
    Q[1, 2] = V10 * M0 * V20 + V11 * M1 * V21
    Q[2, 2] = V20 * M0 * V20 + V21 * M1 * V21
    Q[1, 0] = Q[0, 1]
    Q[2, 0] = Q[0, 2]
    Q[2, 1] = Q[1, 2]
    return STATUS_OK


@njit(cache=True)
def chain_steps(
    kind, p, X, controls, dts, seg_ptr, floor, propagate, xbar, Phi, Sig, Gs
):  # pragma: no cover - compiled
    """Run the motion model along every segment from its start node.

    For step ``t`` of segment ``s`` (from node ``X[s]``): ``xbar[t]`` the predicted pose,
    ``Phi[t] = d xbar[t] / d X[s]``, ``Sig[t]`` the process covariance accumulated since
    ``X[s]`` (``G Sig G^T + V M V^T + floor dt`` per step) and ``Gs[t]`` the step's ``G``.
    With ``propagate`` the end of each segment is written to ``X[s + 1]`` first (dead
    reckoning, Table 11.1). Returns a status.
    """
    xn = np.empty(3)
    G = np.empty((3, 3))
    Q = np.empty((3, 3))
    x = np.empty(3)
    F = np.empty((3, 3))
    S = np.empty((3, 3))
    T1 = np.empty((3, 3))
    for seg in range(seg_ptr.shape[0] - 1):
        for r in range(3):
            x[r] = X[seg, r]
            for k in range(3):
                F[r, k] = 1.0 if r == k else 0.0
                S[r, k] = 0.0
        for t in range(seg_ptr[seg], seg_ptr[seg + 1]):
            dt = dts[t]
            if dt > 0.0:
                st = model_step(kind, p, x, controls[t, 0], controls[t, 1], dt, xn, G, Q)
                if st != STATUS_OK:
                    return st
                # S <- G S G^T + Q + floor dt ; F <- G F
                T1[:] = 0.0
                gemm(G, S, 1.0, T1)
                S[:] = Q
                gemm(T1, G.T, 1.0, S)
                for r in range(3):
                    S[r, r] += floor[r] * dt
                T1[:] = 0.0
                gemm(G, F, 1.0, T1)
                x[:] = xn
                F[:] = T1
            else:
                for r in range(3):
                    for k in range(3):
                        G[r, k] = 1.0 if r == k else 0.0
            for r in range(3):
                xbar[t, r] = x[r]
                for k in range(3):
                    Phi[t, r, k] = F[r, k]
                    Sig[t, r, k] = S[r, k]
                    Gs[t, r, k] = G[r, k]
        if propagate:
            for r in range(3):
                X[seg + 1, r] = x[r]
    return STATUS_OK


@njit(cache=True)
def _inv3(A, out):  # pragma: no cover - compiled
    """Inverse of a symmetric positive definite 3x3 matrix into ``out``; returns False unless
    its leading minors are positive (Sylvester's criterion)."""
    c00 = A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]
    c01 = A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]
    c02 = A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]
    det = A[0, 0] * c00 + A[0, 1] * c01 + A[0, 2] * c02
    minor2 = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    if not (A[0, 0] > 0.0 and minor2 > 0.0 and det > 0.0 and math.isfinite(det)):
        return False
    out[0, 0] = c00 / det
    out[1, 0] = c01 / det
    out[2, 0] = c02 / det
    out[0, 1] = (A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2]) / det
    out[1, 1] = (A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]) / det
    out[2, 1] = (A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1]) / det
    out[0, 2] = (A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1]) / det
    out[1, 2] = (A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]) / det
    out[2, 2] = (A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]) / det
    return True


@njit(cache=True)
def smooth_steps(
    X, P_node, P_cross, seg_ptr, xbar, Phi, Sig, Gs, out_pose, out_cov
):  # pragma: no cover - compiled
    """Poses and marginal covariances of every step between two optimized nodes.

    For step ``t`` of segment ``s`` (nodes ``i = s``, ``j = s + 1``), with the chain run from
    the optimized ``X[i]``: ``C = Cov(w_t, w_j) = Sig[t] Psi^T`` (``Psi = d xbar_j / d xbar_t``),
    ``K = C Sig_j^-1``; the pose is the conditional mean ``xbar[t] + K (X[j] - xbar_j)`` and
    the covariance ``Sig[t] - K C^T + J P J^T`` with ``J = [Phi[t] - K Phi_j, K]`` and ``P`` the
    joint marginal of ``(X[i], X[j])`` (``P_node[i]``, ``P_cross[s] = Cov(X[i], X[j])``,
    ``P_node[j]``): the fixed-interval smoother of the linearized chain, exact for a linear
    model. Returns a status.
    """
    # scratch of the small block products, allocated once before the loop over segments
    Sj_inv = np.empty((3, 3))
    Psi = np.eye(3)
    C = np.empty((3, 3))
    K = np.empty((3, 3))
    J = np.empty((3, 6))
    P = np.empty((6, 6))
    r = np.empty(3)
    tmp = np.empty((3, 3))
    JP = np.empty((3, 6))
    for seg in range(seg_ptr.shape[0] - 1):
        a = seg_ptr[seg]
        b = seg_ptr[seg + 1] - 1
        i = seg
        j = seg + 1
        if not _inv3(Sig[b], Sj_inv):
            return STATUS_SINGULAR_NOISE
        for q in range(3):
            r[q] = X[j, q] - xbar[b, q]
        r[2] = wrap(r[2])
        for q in range(3):
            for m in range(3):
                P[q, m] = P_node[i, q, m]
                P[q, 3 + m] = P_cross[seg, q, m]
                P[3 + q, m] = P_cross[seg, m, q]
                P[3 + q, 3 + m] = P_node[j, q, m]
        for q in range(3):
            for m in range(3):
                Psi[q, m] = 1.0 if q == m else 0.0
        for t in range(b, a - 1, -1):
            # C = Sig[t] Psi^T ; K = C Sj_inv
            C[:] = 0.0
            gemm(Sig[t], Psi.T, 1.0, C)
            K[:] = 0.0
            gemm(C, Sj_inv, 1.0, K)
            for q in range(3):
                acc = xbar[t, q]
                for n in range(3):
                    acc += K[q, n] * r[n]
                out_pose[t, q] = acc
            out_pose[t, 2] = wrap(out_pose[t, 2])
            # J = [Phi[t] - K Phi[b], K]; cov = Sig[t] - K C^T + J P J^T
            J[:, :3] = Phi[t]
            gemm(K, Phi[b], -1.0, J[:, :3])
            J[:, 3:] = K
            JP[:] = 0.0
            gemm(J, P, 1.0, JP)
            out_cov[t] = Sig[t]
            gemm(K, C.T, -1.0, out_cov[t])
            gemm(JP, J.T, 1.0, out_cov[t])
            for q in range(3):
                for m in range(3):
                    out_cov[t, q, m] = 0.5 * (out_cov[t, q, m] + out_cov[t, m, q])
                    out_cov[t, m, q] = out_cov[t, q, m]
            # Psi <- Psi G[t]
            tmp[:] = 0.0
            gemm(Psi, Gs[t], 1.0, tmp)
            Psi[:] = tmp
    return STATUS_OK


@njit(cache=True)
def block_tridiagonal_inverse(D, U, P_node, P_cross):  # pragma: no cover - compiled
    """Diagonal and first off-diagonal 3x3 blocks of ``A^-1`` for a symmetric positive definite
    block-tridiagonal ``A`` (diagonal blocks ``D (K, 3, 3)``, upper blocks ``U (K-1, 3, 3)``,
    ``U[k] = A[k, k+1]``): the information-form Rauch-Tung-Striebel recursion.

    Forward: ``E_0 = D_0``, ``E_k = D_k - U_{k-1}^T E_{k-1}^-1 U_{k-1}``; backward:
    ``P_K-1 = E_K-1^-1``, ``P_{k,k+1} = -E_k^-1 U_k P_{k+1}``,
    ``P_k = E_k^-1 - P_{k,k+1} (E_k^-1 U_k)^T``. Returns False when a pivot block is singular.
    """
    n = D.shape[0]
    Einv = np.empty((n, 3, 3))
    E = np.empty((3, 3))
    W = np.empty((3, 3))
    UW = np.empty((3, 3))
    for k in range(n):
        E[:] = D[k]
        if k > 0:
            # W = E_{k-1}^-1 U_{k-1}; E -= U_{k-1}^T W
            W[:] = 0.0
            gemm(Einv[k - 1], U[k - 1], 1.0, W)
            UW[:] = 0.0
            gemm(U[k - 1].T, W, 1.0, UW)
            E -= UW
        if not _inv3(E, Einv[k]):
            return False
    P_node[n - 1] = Einv[n - 1]
    for k in range(n - 2, -1, -1):
        # W = E_k^-1 U_k ; P_cross[k] = -W P_{k+1} ; P_k = E_k^-1 - P_cross[k] W^T
        W[:] = 0.0
        gemm(Einv[k], U[k], 1.0, W)
        P_cross[k] = 0.0
        gemm(W, P_node[k + 1], -1.0, P_cross[k])
        P_node[k] = Einv[k]
        gemm(P_cross[k], W.T, -1.0, P_node[k])
        for q in range(3):
            for m in range(q + 1, 3):
                v = 0.5 * (P_node[k, q, m] + P_node[k, m, q])
                P_node[k, q, m] = v
                P_node[k, m, q] = v
    return True


@njit(cache=True)
def _range_bearing_one(x, off, m0, m1, zh, Hx, Hm):  # pragma: no cover - compiled
    """Range-bearing prediction ``zh (2,)`` of landmark ``(m0, m1)`` from pose ``x`` with the
    sensor at ``off = (dx, dy, dth)`` in the robot frame, and its Jacobians ``Hx (2, 3)``,
    ``Hm (2, 2)`` (:func:`~probmap.slam.landmark._kernels.range_bearing`). Returns False at
    zero range."""
    r, b = range_bearing(x[0], x[1], x[2], off, m0, m1, Hm, Hx)
    zh[0] = r
    zh[1] = b
    return r > ZERO_RANGE


@njit(cache=True)
def associate_front_end(
    x0, P0, d, Sig, obs_ptr, z, off, Q, gate, new_gate, reach, slot, X, Lm, Pm
):  # pragma: no cover - compiled
    """The GraphSLAM front end (``graphslam_associate``) for the range-bearing model.

    Walks the nodes along the segment increments ``d (K-1, 3)`` with noise ``Sig (K-1, 3, 3)``
    (both in the start node's frame); at node ``s`` associates observations
    ``obs_ptr[s] .. obs_ptr[s + 1] - 1`` of ``z`` by maximum likelihood with mutual exclusion
    against the landmarks within ``reach`` (the arithmetic of ``association.associate_ml``),
    corrects the pose and the matched landmarks in one EKF update and starts a landmark for each
    observation beyond ``new_gate``. Writes ``slot`` (-1: left out), ``X`` and the first ``L``
    rows of ``Lm``, ``Pm``; returns ``L``, or -1 at a zero range.
    """
    K = X.shape[0]
    x = x0.copy()
    P = P0.copy()
    L = 0
    zh = np.empty(2)
    Hx = np.empty((2, 3))
    Hm = np.empty((2, 2))
    F = np.eye(3)
    Rw = np.eye(3)
    n_max = 0
    for s in range(K):
        n_max = max(n_max, obs_ptr[s + 1] - obs_ptr[s])
    cand = np.empty(Lm.shape[0], dtype=np.int64)
    for s in range(K):
        if s > 0:
            c = math.cos(x[2])
            sn = math.sin(x[2])
            dx = d[s - 1, 0]
            dy = d[s - 1, 1]
            F[0, 2] = -sn * dx - c * dy
            F[1, 2] = c * dx - sn * dy
            Rw[0, 0] = c
            Rw[0, 1] = -sn
            Rw[1, 0] = sn
            Rw[1, 1] = c
            x[0] = x[0] + c * dx - sn * dy
            x[1] = x[1] + sn * dx + c * dy
            x[2] = wrap(x[2] + d[s - 1, 2])
            P = F @ P @ F.T + Rw @ Sig[s - 1] @ Rw.T
        a = obs_ptr[s]
        k = obs_ptr[s + 1] - a
        if k > 0:
            nc = 0
            for j in range(L):
                if math.hypot(Lm[j, 0] - x[0], Lm[j, 1] - x[1]) < reach:
                    cand[nc] = j
                    nc += 1
            D2 = np.empty((k, nc))
            cost = np.full((k, nc), np.inf)
            for q in range(nc):
                j = cand[q]
                if not _range_bearing_one(x, off, Lm[j, 0], Lm[j, 1], zh, Hx, Hm):
                    return -1
                S = Hx @ P @ Hx.T + Hm @ Pm[j] @ Hm.T + Q
                det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
                for i in range(k):
                    n0 = z[a + i, 0] - zh[0]
                    n1 = wrap(z[a + i, 1] - zh[1])
                    v = (
                        S[1, 1] * n0 * n0 - (S[0, 1] + S[1, 0]) * n0 * n1 + S[0, 0] * n1 * n1
                    ) / det
                    D2[i, q] = v
                    if v < gate:
                        cost[i, q] = v + math.log(det)
            match = np.full(k, -2, dtype=np.int64)
            done = np.zeros(k, dtype=np.bool_)
            taken = np.zeros(nc, dtype=np.bool_)
            if nc > 0:
                order = np.argsort(cost.ravel())
                for f in order:
                    i = f // nc
                    q = f % nc
                    if not math.isfinite(cost[i, q]):
                        break
                    if done[i] or taken[q]:
                        continue
                    match[i] = q
                    done[i] = True
                    taken[q] = True
            for i in range(k):
                nearest = np.inf
                for q in range(nc):
                    nearest = min(nearest, D2[i, q])
                if not done[i] and nearest > new_gate:
                    match[i] = -1
            m = 0
            for i in range(k):
                if match[i] >= 0:
                    m += 1
            if m > 0:  # one EKF update of the pose and the m matched landmarks
                n = 3 + 2 * m
                mu = np.empty(n)
                C = np.zeros((n, n))
                H = np.zeros((2 * m, n))
                nu = np.empty(2 * m)
                js = np.empty(m, dtype=np.int64)
                for r in range(3):
                    mu[r] = x[r]
                    for t in range(3):
                        C[r, t] = P[r, t]
                p = 0
                for i in range(k):
                    if match[i] < 0:
                        continue
                    j = cand[match[i]]
                    js[p] = j
                    mu[3 + 2 * p] = Lm[j, 0]
                    mu[4 + 2 * p] = Lm[j, 1]
                    for r in range(2):
                        for t in range(2):
                            C[3 + 2 * p + r, 3 + 2 * p + t] = Pm[j, r, t]
                    _range_bearing_one(x, off, Lm[j, 0], Lm[j, 1], zh, Hx, Hm)
                    for r in range(2):
                        for t in range(3):
                            H[2 * p + r, t] = Hx[r, t]
                        for t in range(2):
                            H[2 * p + r, 3 + 2 * p + t] = Hm[r, t]
                    nu[2 * p] = z[a + i, 0] - zh[0]
                    nu[2 * p + 1] = wrap(z[a + i, 1] - zh[1])
                    slot[a + i] = j
                    p += 1
                HC = H @ C
                Sf = HC @ H.T
                for p in range(m):
                    for r in range(2):
                        for t in range(2):
                            Sf[2 * p + r, 2 * p + t] += Q[r, t]
                Kt = np.linalg.solve(Sf, HC)  # K^T
                mu += Kt.T @ nu
                C -= Kt.T @ HC
                x[0] = mu[0]
                x[1] = mu[1]
                x[2] = wrap(mu[2])
                for r in range(3):
                    for t in range(3):
                        P[r, t] = 0.5 * (C[r, t] + C[t, r])
                for p in range(m):
                    j = js[p]
                    Lm[j, 0] = mu[3 + 2 * p]
                    Lm[j, 1] = mu[4 + 2 * p]
                    for r in range(2):
                        for t in range(2):
                            Pm[j, r, t] = 0.5 * (
                                C[3 + 2 * p + r, 3 + 2 * p + t] + C[3 + 2 * p + t, 3 + 2 * p + r]
                            )
            for i in range(k):
                if match[i] != -1:
                    continue
                # a new landmark through the inverse measurement model
                c = math.cos(x[2])
                sn = math.sin(x[2])
                sx = x[0] + c * off[0] - sn * off[1]
                sy = x[1] + sn * off[0] + c * off[1]
                dsx = -sn * off[0] - c * off[1]
                dsy = c * off[0] - sn * off[1]
                rr = z[a + i, 0]
                ang = x[2] + off[2] + z[a + i, 1]
                ca = math.cos(ang)
                sa = math.sin(ang)
                Lm[L, 0] = sx + rr * ca
                Lm[L, 1] = sy + rr * sa
                Jx = np.array([[1.0, 0.0, dsx - rr * sa], [0.0, 1.0, dsy + rr * ca]])
                Jz = np.array([[ca, -rr * sa], [sa, rr * ca]])
                Pm[L] = Jx @ P @ Jx.T + Jz @ Q @ Jz.T
                slot[a + i] = L
                L += 1
        for r in range(3):
            X[s, r] = x[r]
    return L


@njit(cache=True)
def cholesky_symbolic(n, Ap, Ai):  # pragma: no cover - compiled
    """Pattern of the Cholesky factor ``L`` of a sparse symmetric matrix given by its lower
    triangle ``Ap, Ai`` (CSC, rows sorted, diagonal present): column ``j`` of ``L`` is column
    ``j`` of ``A`` joined with the columns of its children in the elimination tree (without
    their own diagonal). Returns ``Lp, Li`` (CSC, rows sorted, diagonal first) and, for the
    left-looking numeric phase, the rows of ``L`` (``Rp``; ``Rk`` the column and ``Rpos`` the
    position in ``Li`` of every strictly lower entry)."""
    head = np.full(n, -1, dtype=np.int64)  # children of each column (linked list)
    nxt = np.full(n, -1, dtype=np.int64)
    mark = np.full(n, -1, dtype=np.int64)
    cap = max(2 * Ap[n], 16)
    Li = np.empty(cap, dtype=np.int64)
    Lp = np.zeros(n + 1, dtype=np.int64)
    buf = np.empty(n, dtype=np.int64)
    for j in range(n):
        m = 0
        for q in range(Ap[j], Ap[j + 1]):
            r = Ai[q]
            if r >= j and mark[r] != j:
                mark[r] = j
                buf[m] = r
                m += 1
        c = head[j]
        while c != -1:
            for q in range(Lp[c] + 1, Lp[c + 1]):
                r = Li[q]
                if mark[r] != j:
                    mark[r] = j
                    buf[m] = r
                    m += 1
            c = nxt[c]
        rows = np.sort(buf[:m])
        if Lp[j] + m > cap:
            while Lp[j] + m > cap:
                cap *= 2
            grown = np.empty(cap, dtype=np.int64)
            grown[: Lp[j]] = Li[: Lp[j]]
            Li = grown
        Li[Lp[j] : Lp[j] + m] = rows
        Lp[j + 1] = Lp[j] + m
        if m > 1:  # parent: the first row below the diagonal
            p = rows[1]
            nxt[j] = head[p]
            head[p] = j
    nnz = Lp[n]
    Li = Li[:nnz].copy()
    cnt = np.zeros(n + 1, dtype=np.int64)
    for k in range(n):
        for q in range(Lp[k] + 1, Lp[k + 1]):
            cnt[Li[q] + 1] += 1
    Rp = np.cumsum(cnt)
    fill = Rp[:-1].copy()
    Rk = np.empty(Rp[n], dtype=np.int64)
    Rpos = np.empty(Rp[n], dtype=np.int64)
    for k in range(n):  # columns in order: every row's entries sorted by column
        for q in range(Lp[k] + 1, Lp[k + 1]):
            r = Li[q]
            Rk[fill[r]] = k
            Rpos[fill[r]] = q
            fill[r] += 1
    return Lp, Li, Rp, Rk, Rpos


@njit(cache=True)
def cholesky_numeric(n, Ap, Ai, Ax, Lp, Li, Rp, Rk, Rpos, Lx):  # pragma: no cover - compiled
    """Left-looking sparse Cholesky ``A = L L^T`` into ``Lx`` on the pattern of
    :func:`cholesky_symbolic`. Returns False if ``A`` is not positive definite."""
    w = np.zeros(n)
    for j in range(n):
        for q in range(Ap[j], Ap[j + 1]):
            w[Ai[q]] = Ax[q]
        for t in range(Rp[j], Rp[j + 1]):  # columns k < j with L[j, k] != 0
            k = Rk[t]
            pos = Rpos[t]
            ljk = Lx[pos]
            for q in range(pos, Lp[k + 1]):
                w[Li[q]] -= Lx[q] * ljk
        d = w[j]
        if not d > 0.0:
            return False
        d = math.sqrt(d)
        Lx[Lp[j]] = d
        w[j] = 0.0
        for q in range(Lp[j] + 1, Lp[j + 1]):
            Lx[q] = w[Li[q]] / d
            w[Li[q]] = 0.0
    return True


@njit(cache=True)
def cholesky_solve(n, Lp, Li, Lx, b):  # pragma: no cover - compiled
    """``(L L^T)^-1 b`` in place (forward, then backward substitution)."""
    for j in range(n):
        b[j] /= Lx[Lp[j]]
        for q in range(Lp[j] + 1, Lp[j + 1]):
            b[Li[q]] -= Lx[q] * b[j]
    for j in range(n - 1, -1, -1):
        acc = b[j]
        for q in range(Lp[j] + 1, Lp[j + 1]):
            acc -= Lx[q] * b[Li[q]]
        b[j] = acc / Lx[Lp[j]]
    return b
