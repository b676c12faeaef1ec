"""Table 11.5 of Probabilistic Robotics: GraphSLAM with known correspondences.

:func:`optimize_graphslam` runs Gauss-Newton with Levenberg-Marquardt damping
(``_gauss_newton``), repeating the linearization until the cost stops falling, optionally from
an incremental start over growing prefixes of the log (``_incremental_start``), and returns a
:class:`GraphSLAMResult`; ``_recover_steps`` recovers the poses of the steps between two pose
variables with the fixed-interval smoother of each segment.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

import probmap.slam.landmark.graphslam._kernels as _k
from probmap._typing import BoolArray, FloatArray, IntArray
from probmap.geometry.se2 import wrap_angle
from probmap.slam.landmark.graphslam.linearize import (
    LinearizedSystem,
    _chi2_gate_2dof,
    _Linearizer,
)
from probmap.slam.landmark.graphslam.problem import (
    GraphSLAMConfig,
    GraphSLAMProblem,
    graphslam_initialize,
    motion_chain,
)
from probmap.slam.landmark.graphslam.solve import (
    _SparseCholesky,
    graphslam_solve_reduced,
    graphslam_solve_schur,
    marginal_covariances,
)

__all__ = [
    "GraphSLAMResult",
    "optimize_graphslam",
]


# -------------------------------------------------------------------------- Table 11.5
@dataclass(frozen=True, eq=False)
class GraphSLAMResult:
    """What :func:`optimize_graphslam` returns.

    Attributes
    ----------
    nodes : ndarray, shape (K, 3)
        Optimized poses of the pose variables.
    landmarks : ndarray, shape (L, 2)
        Optimized landmark positions (slot order of ``problem.landmark_ids``).
    step_poses : ndarray, shape (T, 3)
        The pose after every step (nodes, and the smoothed poses between them).
    step_covariances : ndarray, shape (T, 3, 3) or None
    node_covariances : ndarray, shape (K, 3, 3) or None
    landmark_covariances : ndarray, shape (L, 2, 2) or None
        Marginal covariances (None with ``covariances=False``).
    initial_cost, final_cost : float
        ``J`` (half the weighted squared error) at the start and the end.
    iterations : int
        Linearizations.
    converged : bool
    measurement_chi2 : ndarray, shape (k,)
        ``e^T Q^-1 e`` of every measurement at the solution.
    measurement_weights : ndarray, shape (k,)
        Final IRLS weight of every measurement; 0 for one dropped as an outlier.
    seconds : float
    """

    nodes: FloatArray
    landmarks: FloatArray
    step_poses: FloatArray
    step_covariances: FloatArray | None
    node_covariances: FloatArray | None
    landmark_covariances: FloatArray | None
    initial_cost: float
    final_cost: float
    iterations: int
    converged: bool
    measurement_chi2: FloatArray
    measurement_weights: FloatArray
    seconds: float


def _apply(X: FloatArray, Lm: FloatArray, delta: FloatArray) -> tuple[FloatArray, FloatArray]:
    K = X.shape[0]
    Xn = X + delta[: 3 * K].reshape(K, 3)
    Xn[:, 2] = wrap_angle(Xn[:, 2])
    return Xn, Lm + delta[3 * K :].reshape(-1, 2)


def _gauss_newton(
    lin: _Linearizer, X: FloatArray, Lm: FloatArray, cfg: GraphSLAMConfig
) -> tuple[FloatArray, FloatArray, int, bool, LinearizedSystem]:
    """Repeated linearize-and-solve (Table 11.5) with Levenberg-Marquardt damping."""
    sysm = lin.linearize(X, Lm)
    # Marquardt's damping lam * diag(H): invariant to the very different scales of headings,
    # positions and landmarks (information 1e8 against 1e2 on an MRCLAM log)
    dscale = np.maximum(sysm.H.diagonal(), 1e-12)
    lam = cfg.initial_lambda
    its = 0
    converged = False
    chol = _SparseCholesky()
    while its < cfg.max_iterations:
        its += 1
        accepted = False
        while True:
            Hd = sysm.H
            if lam != 0:  # on the diagonal entries of the fixed pattern (no explicit zero drops)
                Hd = sysm.H.copy()
                Hd.data[lin.pattern.diag] += lam * dscale
            if cfg.solver == "reduced":
                delta = graphslam_solve_reduced(Hd, sysm.b, sysm.n_pose_vars)
            elif cfg.solver == "schur":
                delta = graphslam_solve_schur(Hd, sysm.b, sysm.n_pose_vars)
            else:
                delta = chol.solve(Hd, sysm.b)
            Xn, Ln = _apply(X, Lm, delta)
            # linearize at the trial point at once: steps are mostly accepted, and then the
            # next iteration needs exactly this system (one residual evaluation, not two)
            trial: LinearizedSystem | None
            try:
                trial = lin.linearize(Xn, Ln)
                new_cost = trial.cost
            except ValueError:  # e.g. a landmark moved onto a sensor: reject the step
                trial, new_cost = None, np.inf
            if new_cost <= sysm.cost:
                accepted = True
                break
            lam = max(lam * 10.0, 1e-9)
            if lam > 1e10:
                break
        if not accepted:
            converged = True  # no step lowers the cost: a minimum to working precision
            break
        drop = sysm.cost - new_cost
        X, Lm = Xn, Ln
        lam = lam / 10.0
        assert trial is not None  # accepted steps have a finite cost
        sysm = trial
        dscale = np.maximum(sysm.H.diagonal(), 1e-12)
        if (
            drop <= cfg.relative_tolerance * max(sysm.cost, 1e-300)
            or float(np.abs(delta).max(initial=0.0)) < 1e-12
        ):
            converged = True
            break
    return X, Lm, its, converged, sysm


def _prefix(problem: GraphSLAMProblem, k: int) -> tuple[GraphSLAMProblem, IntArray]:
    """The sub-problem of nodes ``0..k`` (and the landmarks they saw: their slots)."""
    from dataclasses import replace

    n_steps = int(problem.seg_ptr[k])
    keep = problem.obs_node <= k
    used = np.unique(problem.obs_landmark[keep])
    sub = replace(
        problem,
        controls=problem.controls[:n_steps],
        dts=problem.dts[:n_steps],
        seg_ptr=problem.seg_ptr[: k + 1],
        step_node=problem.step_node[:n_steps],
        obs_node=problem.obs_node[keep],
        obs_landmark=np.searchsorted(used, problem.obs_landmark[keep]).astype(np.int64),
        z=problem.z[keep],
        landmark_ids=problem.landmark_ids[used],
    )
    return sub, used


def _incremental_start(
    problem: GraphSLAMProblem,
    cfg: GraphSLAMConfig,
    X: FloatArray,
    Lm: FloatArray,
    active: BoolArray,
) -> tuple[FloatArray, FloatArray]:
    """A starting point for the whole log from growing prefixes (x1.5 nodes at a time): each
    prefix is solved from the previous solution, extended by dead reckoning and first
    sightings (Table 11.1 applied to the new part only). Dead reckoning over a whole log can
    be so far off (MRCLAM robot 1 turns a third too much) that Gauss-Newton crawls from it.
    """
    K = problem.n_nodes
    gate = None if cfg.outlier_probability is None else _chi2_gate_2dof(cfg.outlier_probability)
    stage = _replace_cfg(cfg, max_iterations=min(cfg.max_iterations, 15), covariances=False)
    done = 0  # nodes 0..done are solved
    seen = np.zeros(problem.n_landmarks, dtype=bool)
    inv = problem.measurement_model.inverse
    k = min(K - 1, 32)
    while done < K - 1:
        if done > 0:  # extend: dead reckoning from the solved end, first sightings
            from dataclasses import replace

            view = replace(problem, seg_ptr=problem.seg_ptr[done : k + 1])
            motion_chain(view, X[done : k + 1], cfg.motion_noise_floor, propagate=True)
        sub, used = _prefix(problem, k)
        for i in np.flatnonzero(problem.obs_node <= k):
            j = int(problem.obs_landmark[i])
            if not seen[j]:
                Lm[j] = inv(X[problem.obs_node[i]], problem.z[i])[0]
                seen[j] = True
        lin = _Linearizer(sub, stage)
        keep = problem.obs_node <= k
        lin.active = active[keep].copy()
        Xs, Ls, _, _, sysm = _gauss_newton(lin, X[: k + 1].copy(), Lm[used].copy(), stage)
        if gate is not None and sub.z.shape[0]:
            bad = lin.active & (sysm.chi2 > gate)
            if bad.any():  # measurements the solved prefix rejects stay out from now on
                lin.active &= ~bad
                active[np.flatnonzero(keep)[bad]] = False
                Xs, Ls, _, _, _ = _gauss_newton(lin, Xs, Ls, stage)
        X[: k + 1] = Xs
        Lm[used] = Ls
        done = k
        k = min(K - 1, int(np.ceil(k * 1.5)))
    return X, Lm


def _replace_cfg(cfg: GraphSLAMConfig, **changes: Any) -> GraphSLAMConfig:
    """``dataclasses.replace`` for a config."""
    from dataclasses import replace

    return replace(cfg, **changes)


def optimize_graphslam(
    problem: GraphSLAMProblem,
    config: GraphSLAMConfig | None = None,
    *,
    initial: tuple[FloatArray, FloatArray] | None = None,
) -> GraphSLAMResult:
    """GraphSLAM with known correspondences (Table 11.5): initialize (Table 11.1), then
    linearize (11.2) and solve (11.3-11.4, or the equivalent sparse solve) until the cost stops
    falling; then drop outliers if asked and solve again, and compute the marginals.

    Parameters
    ----------
    problem : GraphSLAMProblem
    config : GraphSLAMConfig, optional
    initial : (X (K, 3), Lm (L, 2)), optional
        Starting point instead of Table 11.1's.

    Returns
    -------
    GraphSLAMResult
    """
    cfg = config if config is not None else GraphSLAMConfig()
    t0 = time.perf_counter()
    active = np.ones(problem.z.shape[0], dtype=bool)
    if initial is None:
        X, Lm = graphslam_initialize(problem, cfg.motion_noise_floor)
        if cfg.initialization == "incremental":
            X, Lm = _incremental_start(problem, cfg, X, Lm, active)
    else:
        X = np.array(initial[0], dtype=np.float64).reshape(problem.n_nodes, 3)
        Lm = np.array(initial[1], dtype=np.float64).reshape(problem.n_landmarks, 2)
    lin = _Linearizer(problem, cfg)
    lin.active = active
    initial_cost, _ = lin.residuals(X, Lm, False)
    X, Lm, its, converged, sysm = _gauss_newton(lin, X, Lm, cfg)
    if cfg.outlier_probability is not None and problem.z.shape[0]:
        gate = _chi2_gate_2dof(cfg.outlier_probability)
        for _ in range(cfg.outlier_rounds):
            bad = lin.active & (sysm.chi2 > gate)
            if not bad.any():
                break
            lin.active &= ~bad
            X, Lm, more, converged, sysm = _gauss_newton(lin, X, Lm, cfg)
            its += more
    step_poses, step_cov, node_cov, lm_cov = _recover_steps(problem, cfg, X, Lm, sysm)
    return GraphSLAMResult(
        nodes=X,
        landmarks=Lm,
        step_poses=step_poses,
        step_covariances=step_cov,
        node_covariances=node_cov,
        landmark_covariances=lm_cov,
        initial_cost=float(initial_cost),
        final_cost=float(sysm.cost),
        iterations=its,
        converged=converged,
        measurement_chi2=sysm.chi2,
        measurement_weights=sysm.weights,
        seconds=time.perf_counter() - t0,
    )


def _recover_steps(
    problem: GraphSLAMProblem,
    cfg: GraphSLAMConfig,
    X: FloatArray,
    Lm: FloatArray,
    sysm: LinearizedSystem,
) -> tuple[FloatArray, FloatArray | None, FloatArray | None, FloatArray | None]:
    """Poses (and covariances) of every step from the optimized nodes."""
    K = problem.n_nodes
    T = problem.step_node.size
    if cfg.covariances:
        Pn, Pc, Lc = marginal_covariances(sysm.H, K, problem.n_landmarks)
    else:
        Pn = np.zeros((K, 3, 3))
        Pc = np.zeros((max(K - 1, 0), 3, 3))
        Lc = None
    poses = np.empty((T, 3))
    covs = np.empty((T, 3, 3))
    n = int(problem.seg_ptr[-1])
    if K > 1:
        ch = motion_chain(problem, X, cfg.motion_noise_floor)
        status = _k.smooth_steps(
            X, Pn, Pc, problem.seg_ptr, ch.xbar, ch.Phi, ch.Sig, ch.G, poses[:n], covs[:n]
        )
        if status != _k.STATUS_OK:
            raise ValueError("singular odometry noise between two poses: raise motion_noise_floor")
    poses[n:] = X[-1]
    covs[n:] = Pn[-1]
    if not cfg.covariances:
        return poses, None, None, None
    return poses, covs, Pn, Lc
