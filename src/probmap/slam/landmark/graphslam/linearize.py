"""Table 11.2 of Probabilistic Robotics: the linearized GraphSLAM system.

:func:`graphslam_linearize` (with ``_Linearizer``, which keeps the fixed sparsity pattern of
``H`` between iterations) builds the information matrix ``H`` and the vector ``b`` of the
system ``H delta = b`` as a :class:`LinearizedSystem`, with the robust weights of the
measurement factors (``_robust``: Huber or Cauchy) and the chi-square gate of 2 degrees of
freedom (``_chi2_gate_2dof``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from probmap._typing import FloatArray, IntArray
from probmap.geometry.se2 import wrap_angle
from probmap.slam.landmark.graphslam.problem import (
    GraphSLAMConfig,
    GraphSLAMProblem,
    _measurements,
    _model_params,
    motion_chain,
)

__all__ = [
    "LinearizedSystem",
    "graphslam_linearize",
]


# -------------------------------------------------------------------------- Table 11.2
class _Pattern:
    """The fixed sparsity pattern of ``H``: factor blocks scattered into CSC data by index."""

    def __init__(self, rows: IntArray, cols: IntArray, n: int) -> None:
        # column-major keys: sorted keys are CSC order (columns sorted, rows sorted inside)
        key = cols * n + rows
        uniq, pos = np.unique(key, return_inverse=True)
        self.pos = pos.astype(np.int64).reshape(-1)
        self.nnz = int(uniq.size)
        r = uniq % n
        c = uniq // n
        self.indices = r.astype(np.int32)
        self.indptr = np.searchsorted(c, np.arange(n + 1)).astype(np.int32)
        self.n = n
        # position of (j, j) in the data (every diagonal entry is in the pattern)
        self.diag = np.searchsorted(uniq, np.arange(n, dtype=np.int64) * (n + 1))

    def matrix(self, values: FloatArray) -> sp.csc_matrix:
        data = np.bincount(self.pos, weights=values, minlength=self.nnz)
        return sp.csc_matrix((data, self.indices, self.indptr), shape=(self.n, self.n))


def _block_index(first: IntArray, width: int) -> IntArray:
    return first[:, None] + np.arange(width)


@dataclass(frozen=True, eq=False)
class LinearizedSystem:
    """The linearized GraphSLAM system of Table 11.2, for the increment: ``H delta = b``.

    Attributes
    ----------
    H : scipy.sparse.csc_matrix, shape (3K + 2L, 3K + 2L)
        Information matrix ``Omega`` (poses first, node ``n`` at ``3n``, then landmark ``j`` at
        ``3K + 2j``).
    b : ndarray, shape (3K + 2L,)
        ``-J^T W e``; the book's ``xi`` is ``H mu + b``.
    cost : float
        ``J`` at the linearization point (robust terms as ``rho``).
    chi2 : ndarray, shape (k,)
        ``e^T Q^-1 e`` of every measurement.
    weights : ndarray, shape (k,)
        IRLS weights of the measurements (0 for dropped ones).
    n_pose_vars : int
        ``3K``.
    """

    H: sp.csc_matrix
    b: FloatArray
    cost: float
    chi2: FloatArray
    weights: FloatArray
    n_pose_vars: int


class _Linearizer:
    """Builds :class:`LinearizedSystem` for one problem (its pattern is computed once)."""

    def __init__(self, problem: GraphSLAMProblem, config: GraphSLAMConfig) -> None:
        self.p = problem
        self.cfg = config
        K, L = problem.n_nodes, problem.n_landmarks
        self.n = 3 * K + 2 * L
        R = np.asarray(problem.measurement_model.R, dtype=np.float64)
        self.R_inv = np.linalg.inv(R)
        seg = np.arange(K - 1, dtype=np.int64)
        self.idx_motion = np.hstack([_block_index(3 * seg, 3), _block_index(3 * seg + 3, 3)])
        self.idx_meas = np.hstack(
            [
                _block_index(3 * problem.obs_node, 3),
                _block_index(3 * K + 2 * problem.obs_landmark, 2),
            ]
        )
        self.idx_prior = np.arange(3, dtype=np.int64)[None, :]
        rows, cols = [], []
        for idx in (self.idx_prior, self.idx_motion, self.idx_meas):
            d = idx.shape[1]
            rows.append(np.repeat(idx, d, axis=1).ravel())
            cols.append(np.tile(idx, (1, d)).ravel())
        self.pattern = _Pattern(np.concatenate(rows), np.concatenate(cols), self.n)
        self.active = np.ones(problem.z.shape[0], dtype=bool)
        # the package's motion models move in the robot frame (g(x, u) = x (+) g(0, u)), so the
        # odometry residual is taken in the start node's frame, where its noise is constant
        self.invariant = _model_params(problem.motion_model) is not None
        if self.invariant and K > 1:
            ch = motion_chain(problem, np.zeros((K, 3)), config.motion_noise_floor)
            end = problem.seg_ptr[1:] - 1
            self.body_delta = ch.xbar[end]
            self.body_information = _information(ch.Sig[end])

    def residuals(
        self, X: FloatArray, Lm: FloatArray, jacobians: bool
    ) -> tuple[float, dict[str, Any]]:
        p = self.p
        floor = self.cfg.motion_noise_floor
        out: dict[str, Any] = {}
        # prior
        e0 = X[0] - p.prior_mean
        e0[2] = wrap_angle(e0[2])
        cost = float(e0 @ p.prior_information @ e0)
        out["prior"] = e0
        # motion factors between consecutive nodes
        if p.n_nodes > 1:
            if self.invariant:
                # g(x, u) = x (+) g(0, u): each segment's increment and noise in its start
                # node's frame were chained once (from the origin); compose them here
                d, S = self.body_delta, None
                ci, si = np.cos(X[:-1, 2]), np.sin(X[:-1, 2])
                pred = np.column_stack(
                    [
                        X[:-1, 0] + ci * d[:, 0] - si * d[:, 1],
                        X[:-1, 1] + si * d[:, 0] + ci * d[:, 1],
                        wrap_angle(X[:-1, 2] + d[:, 2]),
                    ]
                )
                F = np.zeros((ci.size, 3, 3))
                F[:, 0, 0] = F[:, 1, 1] = F[:, 2, 2] = 1.0
                F[:, 0, 2] = -si * d[:, 0] - ci * d[:, 1]
                F[:, 1, 2] = ci * d[:, 0] - si * d[:, 1]
            else:
                ch = motion_chain(p, X, floor)
                end = p.seg_ptr[1:] - 1
                pred, F, S = ch.xbar[end], ch.Phi[end], ch.Sig[end]
            ew = X[1:] - pred
            ew[:, 2] = wrap_angle(ew[:, 2])
            # in the frame of the start node: e_b = Rt(theta_i) e_w, Rt = blockdiag(R^T, 1);
            # for the package's (rotation-invariant) models the noise Rt S Rt^T is then
            # constant, so the cost is exact and so are its Jacobians
            c, s = np.cos(X[:-1, 2]), np.sin(X[:-1, 2])
            if not self.invariant:  # any other model: the book's world-frame residual
                c, s = np.ones_like(c), np.zeros_like(s)
            Rt = np.zeros((c.size, 3, 3))
            Rt[:, 0, 0], Rt[:, 0, 1], Rt[:, 1, 0], Rt[:, 1, 1] = c, s, -s, c
            Rt[:, 2, 2] = 1.0
            em = (Rt @ ew[:, :, None])[:, :, 0]
            if S is None:
                Om = self.body_information
            else:
                Om = _information(np.einsum("sij,sjk,slk->sil", Rt, S, Rt))
            cost += float(((Om @ em[:, :, None])[:, :, 0] * em).sum())
            if jacobians:
                Ji = -(Rt @ F)
                if self.invariant:
                    Ji[:, 0, 2] += -s * ew[:, 0] + c * ew[:, 1]
                    Ji[:, 1, 2] += -c * ew[:, 0] - s * ew[:, 1]
                out["motion"] = (em, np.concatenate([Ji, Rt], axis=2), Om)
        # measurements
        if p.z.shape[0]:
            zh, Hx, Hm = _measurements(p.measurement_model, X, Lm, p.obs_node, p.obs_landmark)
            ez = zh - p.z
            ez[:, 1] = wrap_angle(ez[:, 1])
            chi2 = ((ez @ self.R_inv) * ez).sum(axis=1)
            rho, w = _robust(chi2, self.cfg.robust, self.cfg.scale)
            rho = np.where(self.active, rho, 0.0)
            w = np.where(self.active, w, 0.0)
            cost += float(rho.sum())
            out["meas"] = (ez, Hx, Hm, chi2, w)
        return 0.5 * cost, out

    def linearize(self, X: FloatArray, Lm: FloatArray) -> LinearizedSystem:
        cost, r = self.residuals(X, Lm, True)
        p = self.p
        b = np.zeros(self.n)
        vals = [p.prior_information.ravel()]
        b[:3] -= p.prior_information @ r["prior"]
        if "motion" in r:
            em, J, Om = r["motion"]  # J (S, 3, 6): d e / d (x_i, x_j)
            JtO = J.transpose(0, 2, 1) @ Om  # (S, 6, 3)
            vals.append((JtO @ J).ravel())
            np.add.at(b, self.idx_motion, -(JtO @ em[:, :, None])[:, :, 0])
        chi2 = np.zeros(0)
        w = np.zeros(0)
        if "meas" in r:
            ez, Hx, Hm, chi2, w = r["meas"]
            J = np.concatenate([Hx, Hm], axis=2)  # (k, 2, 5)
            JtO = (J.transpose(0, 2, 1) @ self.R_inv) * w[:, None, None]
            vals.append((JtO @ J).ravel())
            np.add.at(b, self.idx_meas, -(JtO @ ez[:, :, None])[:, :, 0])
        H = self.pattern.matrix(np.concatenate(vals))
        return LinearizedSystem(H, b, cost, chi2, w, 3 * p.n_nodes)


def _chi2_gate_2dof(probability: float) -> float:
    """Chi-square quantile with 2 degrees of freedom, ``-2 log(1 - p)`` (closed form)."""
    return float(-2.0 * np.log1p(-probability))


def _information(S: FloatArray) -> FloatArray:
    try:
        return np.asarray(np.linalg.inv(S), dtype=np.float64)
    except np.linalg.LinAlgError as exc:
        raise ValueError(
            "singular odometry noise between two poses: raise motion_noise_floor"
        ) from exc


def _robust(chi2: FloatArray, kernel: str, scale: float) -> tuple[FloatArray, FloatArray]:
    """``rho(s)`` and the IRLS weight ``d rho / d s`` of squared Mahalanobis distances."""
    if kernel == "huber":
        d = np.sqrt(chi2)
        big = d > scale
        rho = np.where(big, 2.0 * scale * d - scale * scale, chi2)
        return rho, np.where(big, scale / np.maximum(d, 1e-300), 1.0)
    if kernel == "cauchy":
        k2 = scale * scale
        return k2 * np.log1p(chi2 / k2), 1.0 / (1.0 + chi2 / k2)
    return chi2.copy(), np.ones_like(chi2)


def graphslam_linearize(
    problem: GraphSLAMProblem,
    X: FloatArray,
    Lm: FloatArray,
    config: GraphSLAMConfig | None = None,
) -> LinearizedSystem:
    """Linearize every factor at ``(X, Lm)`` (Table 11.2) into the sparse information form.

    Prior: ``Omega_0`` on node 0. Motion factor between nodes ``i`` and ``j``: residual
    ``x_j - g(x_i)`` (the model chained over the steps between them), Jacobians ``-G`` (the
    product of the steps' ``G``) and ``I``, information ``R^-1`` with ``R`` the accumulated
    ``G R G^T + V M V^T`` (plus the noise floor). Measurement ``i`` of node ``t``: residual
    ``h(x_t, m_j) - z`` (bearing wrapped), Jacobians ``H_x``, ``H_m`` of the sensor model,
    information ``w Q^-1`` with ``w`` the robust weight (Table 11.2 lines 11-21 with
    ``Q^-1``).
    """
    cfg = config if config is not None else GraphSLAMConfig()
    return _Linearizer(problem, cfg).linearize(X, Lm)
