"""Tables 11.3-11.4 of Probabilistic Robotics: reducing and solving the GraphSLAM system,
and the marginal covariances at the solution.

:func:`graphslam_reduce` marginalizes every landmark into the pose block and
:func:`graphslam_solve_reduced` solves for the poses and recovers the landmarks (Tables
11.3-11.4); ``_SparseCholesky`` factors the whole system by sparse Cholesky with a
fill-reducing ordering (numba kernels, symbolic factorization once per problem), and
:func:`graphslam_solve_schur` solves through the Schur complement with a banded Cholesky of
the pose block. :func:`marginal_covariances` gives the marginals of the poses and landmarks
(block-tridiagonal inverse of the pose chain and the landmarks' Schur complement).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

import probmap.slam.landmark.graphslam._kernels as _k
from probmap._typing import FloatArray, IntArray

__all__ = [
    "graphslam_reduce",
    "graphslam_solve_reduced",
    "graphslam_solve_schur",
    "marginal_covariances",
]


# ---------------------------------------------------------------------- Tables 11.3-11.4
def _landmark_blocks_inverse(C: sp.spmatrix, L: int) -> sp.csr_matrix:
    """Inverse of the block-diagonal landmark information ``Omega_mm`` (2x2 blocks)."""
    Cd = C.tocsr()
    i = np.arange(L) * 2
    a = np.asarray(Cd[i, i]).ravel()
    bq = np.asarray(Cd[i, i + 1]).ravel()
    d = np.asarray(Cd[i + 1, i + 1]).ravel()
    det = a * d - bq * bq
    if np.any(~(det > 0)):
        raise ValueError("a landmark's information block is singular (seen from one place only?)")
    blocks = np.stack([np.stack([d, -bq], -1), np.stack([-bq, a], -1)], 1) / det[:, None, None]
    return sp.block_diag(list(blocks), format="csr") if L else sp.csr_matrix((0, 0))


def graphslam_reduce(
    H: sp.spmatrix, b: FloatArray, n_pose_vars: int
) -> tuple[sp.csc_matrix, FloatArray]:
    """Marginalize the landmarks out of the information form (Table 11.3).

    For every landmark ``j`` with the poses ``tau(j)`` that observed it, Table 11.3 subtracts
    ``Omega_{tau(j),j} Omega_{j,j}^-1 Omega_{j,tau(j)}`` from the pose block and
    ``Omega_{tau(j),j} Omega_{j,j}^-1 xi_j`` from the pose vector. No factor joins two
    landmarks, so ``Omega_mm`` is block diagonal and the loop over ``j`` is one sparse product:
    ``H~ = H_xx - H_xm H_mm^-1 H_mx``, ``b~ = b_x - H_xm H_mm^-1 b_m``.

    Returns
    -------
    H_reduced : scipy.sparse.csc_matrix, shape (3K, 3K)
    b_reduced : ndarray, shape (3K,)
    """
    Hc = sp.csc_matrix(H)
    n = Hc.shape[0]
    L = (n - n_pose_vars) // 2
    A = Hc[:n_pose_vars, :n_pose_vars]
    B = Hc[:n_pose_vars, n_pose_vars:]
    Cinv = _landmark_blocks_inverse(Hc[n_pose_vars:, n_pose_vars:], L)
    BC = B @ Cinv
    Hr = sp.csc_matrix(A - BC @ B.T)
    br = b[:n_pose_vars] - BC @ b[n_pose_vars:]
    return Hr, np.asarray(br, dtype=np.float64)


def graphslam_solve_reduced(H: sp.spmatrix, b: FloatArray, n_pose_vars: int) -> FloatArray:
    """Solve ``H delta = b`` through the reduced system (Tables 11.3-11.4).

    Poses: ``delta_x = H~^-1 b~`` (Table 11.4 lines 2-3). Each landmark from its own block
    given the poses: ``delta_j = Omega_jj^-1 (b_j - Omega_{j,tau(j)} delta_tau(j))`` (line 6).
    """
    Hc = sp.csc_matrix(H)
    n = Hc.shape[0]
    L = (n - n_pose_vars) // 2
    Hr, br = graphslam_reduce(Hc, b, n_pose_vars)
    dx = _sparse_solve(Hr, br)
    if L == 0:
        return dx
    Cinv = _landmark_blocks_inverse(Hc[n_pose_vars:, n_pose_vars:], L)
    Bt = Hc[n_pose_vars:, :n_pose_vars]
    dm = Cinv @ (b[n_pose_vars:] - Bt @ dx)
    return np.concatenate([dx, dm])


def _sparse_solve(H: sp.spmatrix, b: FloatArray) -> FloatArray:
    """``H^-1 b`` for a symmetric positive definite sparse ``H`` (SuperLU, symmetric mode,
    minimum-degree ordering on ``H``)."""
    if H.shape[0] == 0:
        return np.zeros(0)
    try:
        lu = splu(
            sp.csc_matrix(H),
            permc_spec="MMD_AT_PLUS_A",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )
    except RuntimeError as exc:  # "Factor is exactly singular"
        raise ValueError(f"the information matrix is singular ({exc})") from exc
    x = np.asarray(lu.solve(b), dtype=np.float64)
    if not np.all(np.isfinite(x)):
        raise ValueError("the information matrix is singular (non-finite solution)")
    return x


class _SparseCholesky:
    """Sparse Cholesky solves of a sequence of systems with one sparsity pattern (the
    Gauss-Newton iterations of one problem): the fill-reducing ordering (SuperLU's minimum
    degree on ``H + H^T``) and the symbolic factorization (the pattern of ``L``) are computed
    once, and each iteration runs only the numeric factorization (left-looking, numba) and two
    triangular solves. SuperLU refactors from scratch every time (ordering, symbolic, LU of a
    symmetric matrix), which is what dominated GraphSLAM's iterations on Victoria Park."""

    def __init__(self) -> None:
        self.indptr: IntArray | None = None
        self.indices: IntArray | None = None

    def _analyze(self, H: sp.csc_matrix) -> Any:
        n = H.shape[0]
        lu = splu(
            H, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
        )
        pinv = np.asarray(lu.perm_c, dtype=np.int64)  # old index -> new
        self.perm = np.argsort(pinv)  # new index -> old
        cols = np.repeat(np.arange(n, dtype=np.int64), np.diff(H.indptr))
        a, c = pinv[H.indices], pinv[cols]
        t = np.flatnonzero(a >= c)  # the lower triangle of the permuted matrix
        order = np.lexsort((a[t], c[t]))
        self.tmap = t[order]
        self.Ai = a[self.tmap]
        self.Ap = np.searchsorted(c[self.tmap], np.arange(n + 1)).astype(np.int64)
        self.Lp, self.Li, self.Rp, self.Rk, self.Rpos = _k.cholesky_symbolic(n, self.Ap, self.Ai)
        self.indptr, self.indices = H.indptr.copy(), H.indices.copy()
        return lu

    def solve(self, H: sp.spmatrix, b: FloatArray) -> FloatArray:
        Hc = sp.csc_matrix(H)
        Hc.sort_indices()
        n = Hc.shape[0]
        if n == 0:
            return np.zeros(0)
        if not (
            self.indptr is not None
            and self.indices is not None
            and np.array_equal(self.indptr, Hc.indptr)
            and np.array_equal(self.indices, Hc.indices)
        ):
            try:
                lu = self._analyze(Hc)
            except RuntimeError as exc:  # "Factor is exactly singular"
                raise ValueError(f"the information matrix is singular ({exc})") from exc
            x = np.asarray(lu.solve(b), dtype=np.float64)  # the ordering's LU solves this one
            if not np.all(np.isfinite(x)):
                raise ValueError("the information matrix is singular (non-finite solution)")
            return x
        Lx = np.empty(self.Li.size)
        Ax = np.ascontiguousarray(Hc.data[self.tmap], dtype=np.float64)
        ok = _k.cholesky_numeric(
            n, self.Ap, self.Ai, Ax, self.Lp, self.Li, self.Rp, self.Rk, self.Rpos, Lx
        )
        if not ok:  # not positive definite to working precision: the general LU decides
            return _sparse_solve(Hc, b)
        y = np.ascontiguousarray(b[self.perm], dtype=np.float64)
        _k.cholesky_solve(n, self.Lp, self.Li, Lx, y)
        x = np.empty(n)
        x[self.perm] = y
        if not np.all(np.isfinite(x)):
            raise ValueError("the information matrix is singular (non-finite solution)")
        return x


def _pose_band(A: sp.spmatrix) -> FloatArray:
    """Upper band storage (``scipy.linalg.cholesky_banded``, 5 superdiagonals) of the pose
    block, which is block tridiagonal with 3x3 blocks (a chain of motion factors)."""
    Ac = sp.csr_matrix(A)
    n = Ac.shape[0]
    coo = Ac.tocoo()
    if coo.nnz and int(np.abs(coo.row - coo.col).max()) > 5:
        raise ValueError("the pose block is not a chain of 3x3 blocks")
    ab = np.zeros((6, n))
    for k in range(6):
        ab[5 - k, k:] = Ac.diagonal(k)
    return ab


def _banded_cholesky(A: sp.spmatrix) -> FloatArray:
    from scipy.linalg import cholesky_banded

    try:
        return np.asarray(cholesky_banded(_pose_band(A)), dtype=np.float64)
    except np.linalg.LinAlgError as exc:
        raise ValueError("the pose information matrix is not positive definite") from exc


def graphslam_solve_schur(H: sp.spmatrix, b: FloatArray, n_pose_vars: int) -> FloatArray:
    """Solve ``H delta = b`` by eliminating the poses instead of the landmarks.

    The pose block ``A`` is a chain (block tridiagonal, bandwidth 5), so ``W = A^-1 [B, b_x]``
    costs O(K L) with a banded Cholesky factor; the landmarks then solve their dense Schur
    complement ``S = C - B^T A^-1 B`` (2L x 2L) and the poses follow by back-substitution.
    The same answer as :func:`graphslam_solve_reduced` (the book's order) and the sparse LU,
    at a cost linear in the length of the log for a fixed map.
    """
    from scipy.linalg import cho_solve_banded

    Hc = sp.csr_matrix(H)
    npv = n_pose_vars
    cb = _banded_cholesky(Hc[:npv, :npv])
    if Hc.shape[0] == npv:
        return np.asarray(cho_solve_banded((cb, False), b), dtype=np.float64)
    Bs = sp.csc_matrix(Hc[:npv, npv:])
    C = Hc[npv:, npv:].toarray()
    W = cho_solve_banded((cb, False), np.column_stack([Bs.toarray(), b[:npv]]))
    BtW = np.asarray(Bs.T @ W)  # B is sparse: a landmark sees few poses
    S = C - BtW[:, :-1]
    rhs = b[npv:] - BtW[:, -1]
    try:
        dm = np.linalg.solve(0.5 * (S + S.T), rhs)
    except np.linalg.LinAlgError as exc:
        raise ValueError("the landmark information (Schur complement) is singular") from exc
    dx = W[:, -1] - W[:, :-1] @ dm
    return np.concatenate([dx, dm])


# -------------------------------------------------------------------------- covariances
def marginal_covariances(
    H: sp.spmatrix, n_nodes: int, n_landmarks: int
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Marginal covariances from the information matrix at the solution.

    ``H = [[A, B], [B^T, C]]`` with ``A`` the block-tridiagonal pose block (a chain of motion
    factors). With ``W = A^-1 B`` and the landmark Schur complement ``S = C - B^T W``:
    ``Cov(m) = S^-1`` and the pose blocks ``Cov(x)_{ik} = (A^-1)_{ik} + W_i S^-1 W_k^T``, whose
    ``A^-1`` blocks on and next to the diagonal come from an information-form
    Rauch-Tung-Striebel recursion.

    Returns
    -------
    pose_cov : ndarray, shape (K, 3, 3)
    cross_cov : ndarray, shape (K - 1, 3, 3)
        ``Cov(x_s, x_{s+1})``.
    landmark_cov : ndarray, shape (L, 2, 2)
    """
    Hc = sp.csr_matrix(H)
    K, L = n_nodes, n_landmarks
    npv = 3 * K
    A = Hc[:npv, :npv]
    i = np.arange(K)
    r3 = np.arange(3)
    rows = np.broadcast_to((3 * i)[:, None, None] + r3[:, None], (K, 3, 3))
    cols = np.broadcast_to((3 * i)[:, None, None] + r3[None, :], (K, 3, 3))
    D = np.asarray(A[rows.ravel(), cols.ravel()]).reshape(K, 3, 3)
    if K > 1:
        U = np.asarray(A[rows[:-1].ravel(), (cols[:-1] + 3).ravel()]).reshape(K - 1, 3, 3)
    else:
        U = np.zeros((0, 3, 3))
    Pn = np.empty((K, 3, 3))
    Pc = np.empty((max(K - 1, 0), 3, 3))
    if not _k.block_tridiagonal_inverse(np.ascontiguousarray(D), np.ascontiguousarray(U), Pn, Pc):
        raise ValueError("the pose information matrix is singular")
    Lc = np.zeros((L, 2, 2))
    if L:
        Bs = sp.csc_matrix(Hc[:npv, npv:])
        C = Hc[npv:, npv:].toarray()
        from scipy.linalg import cho_solve_banded

        W = cho_solve_banded((_banded_cholesky(A), False), Bs.toarray(), overwrite_b=True)
        S = C - np.asarray(Bs.T @ W)  # B is sparse: a landmark sees few poses
        Sm = np.linalg.inv(0.5 * (S + S.T))
        j = np.arange(L)
        Lc = Sm.reshape(L, 2, L, 2)[j, :, j, :]
        Wr = W.reshape(K, 3, 2 * L)
        step = 1024  # nodes per GEMM: large products, and no second (3K, 2L) array
        for a in range(0, K, step):
            e = min(K, a + step) - a
            WS = (W[3 * a : 3 * (a + e)] @ Sm).reshape(e, 3, 2 * L)
            Pn[a : a + e] += WS[:e] @ Wr[a : a + e].transpose(0, 2, 1)
            n_cross = min(e, K - 1 - a)
            if n_cross > 0:
                Pc[a : a + n_cross] += WS[:n_cross] @ Wr[a + 1 : a + 1 + n_cross].transpose(0, 2, 1)
    return Pn, Pc, Lc
