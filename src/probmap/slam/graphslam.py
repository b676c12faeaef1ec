"""GraphSLAM for point landmarks (Probabilistic Robotics, chapter 11), known correspondences.

The full-SLAM posterior over the whole path and the map is the minimum of

.. math:: J = (x_0 - \\mu_0)^T \\Omega_0 (x_0 - \\mu_0)
          + \\sum_t (x_t - g(u_t, x_{t-1}))^T R_t^{-1} (x_t - g(u_t, x_{t-1}))
          + \\sum_{t,i} \\rho\\big((z_t^i - h(x_t, m_{c_t^i}))^T Q^{-1} (z_t^i - h(\\cdot))\\big)

(eq. 11.4-11.5 with the anchoring prior of Table 11.2 line 2 and an optional robust ``rho``).
The motion model ``g`` and its noise are those of the EKF (``predict`` and
``control_covariance`` of :mod:`probmap.models.motion`: ``R_t = V M V^T``), and the measurement
model ``h`` with ``Q`` is :class:`~probmap.models.measurement.RangeBearingModel`.

How the book's tables map onto this module:

* Table 11.1 (initialize): :func:`graphslam_initialize` dead-reckons the poses and places each
  landmark at its first sighting (the inverse measurement model).
* Table 11.2 (linearize): :func:`graphslam_linearize` builds the information matrix ``Omega``
  (here ``H``) and vector of the linearized system as a ``scipy.sparse`` matrix. It is written
  for the increment ``delta`` (``H delta = b``, ``b = -J^T W e``): the book's ``xi`` is
  ``H mu + b`` and its solution ``mu = Omega^-1 xi`` is our ``mu + delta``.
* Tables 11.3-11.4 (reduce, solve): :func:`graphslam_reduce` marginalizes every landmark into
  the pose block (``Omega~ = Omega_xx - Omega_xm Omega_mm^-1 Omega_mx``, with ``Omega_mm`` block
  diagonal because no factor joins two landmarks), :func:`graphslam_solve_reduced` solves for
  the poses and recovers each landmark from its own block (Table 11.4 line 6). This is an exact
  reformulation of the full sparse solve (``GraphSLAMConfig(solver="reduced")``; a test checks
  both agree); ``solver="sparse"`` factors the whole system by sparse Cholesky with a
  fill-reducing ordering instead (SuperLU's minimum degree; ordering and symbolic factorization
  once per problem), which never forms the reduced pose matrix (it fills in wherever poses share
  a landmark).
* Table 11.5 (the known-correspondence loop): :func:`optimize_graphslam`, Gauss-Newton with
  Levenberg-Marquardt damping, repeated linearization until the cost stops falling.
* Tables 11.8-11.9 (unknown correspondences): :func:`graphslam_correspondence_test` is the
  test of Table 11.8. :func:`optimize_graphslam_unknown` runs Table 11.9 from one hypothesis
  per observation with the joint covariance of all landmarks (small maps);
  :func:`optimize_graphslam_front_end` (what :class:`GraphSLAM` runs for ids -1) starts from
  the correspondences of an incremental maximum-likelihood front end
  (:func:`graphslam_associate`), solves sparsely and tests only the landmark pairs a KD-tree
  finds close, with their covariances from one sparse factorization
  (:func:`landmark_pair_covariances`): Victoria Park's 48,000 detections in seconds.

Odometry arrives much faster than observations (60,000 records against 1,700 observation times
on an MRCLAM robot), so by default only the steps with observations (and the last step) carry a
pose variable; the motion between two of them is one factor whose prediction, Jacobian and
noise are the model chained over the steps in between (``G`` products and ``G R G^T + V M V^T``
sums), which is the linearized marginal of the intermediate poses. ``keyframes="all"`` gives
every step its own pose, as printed in the book. The intermediate poses are recovered after
the solve by the fixed-interval smoother of each segment, with their marginal covariances. The
velocity model's ``V M V^T`` has rank 2 (no final rotation), so a small variance per second,
``motion_noise_floor``, is added to every step's noise to keep ``R_t`` invertible.

Covariances (for ANEES): the marginals of the final poses and landmarks are blocks of the
inverse of the information matrix at the solution: the pose block is block tridiagonal (a
chain), whose inverse blocks come from an information-form Rauch-Tung-Striebel recursion, and
the landmarks enter through their dense Schur complement.

Two tiers, as the other estimators: array functions (above) and the thin :class:`GraphSLAM`,
which records the steps of a log like an online estimator (``predict``, ``update``) and solves
the whole log in :meth:`GraphSLAM.smooth`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.sparse.linalg import splu

from probmap._checks import is_finite_number, require_integer
from probmap._typing import BoolArray, FloatArray, IntArray
from probmap.geometry.se2 import wrap_angle
from probmap.models.measurement import RangeBearingModel
from probmap.models.motion import AckermannModel, VelocityModel
from probmap.slam import _graphslam_kernels as _k
from probmap.slam.landmark.association import (
    validate_control,
    validate_initial_state,
    validate_observations,
)

__all__ = [
    "GraphSLAM",
    "GraphSLAMConfig",
    "GraphSLAMProblem",
    "GraphSLAMResult",
    "LinearizedSystem",
    "build_graphslam",
    "graphslam_initialize",
    "graphslam_linearize",
    "graphslam_reduce",
    "graphslam_solve_reduced",
    "graphslam_solve_schur",
    "graphslam_correspondence_test",
    "landmark_joint_covariance",
    "optimize_graphslam_unknown",
    "optimize_graphslam_front_end",
    "graphslam_associate",
    "landmark_pair_covariances",
    "marginal_covariances",
    "optimize_graphslam",
    "segment_log",
]

GraphSLAMRobust = Literal["none", "huber", "cauchy"]
# Huber and Cauchy at 95 % asymptotic efficiency (Mahalanobis-distance units), as the pose graph
_DEFAULT_SCALE = {"none": 1.0, "huber": 1.345, "cauchy": 2.3849}


@dataclass(frozen=True)
class GraphSLAMConfig:
    """Settings of :func:`optimize_graphslam` and :class:`GraphSLAM`.

    Parameters
    ----------
    max_iterations : int
        Most linearizations (Table 11.5's repeat loop).
    relative_tolerance : float
        Converged when an accepted step lowers the cost by less than this fraction of it.
    initial_lambda : float
        Levenberg-Marquardt damping of the first step, relative to the largest diagonal entry
        of the information matrix (0 would be plain Gauss-Newton).
    robust : {"none", "huber", "cauchy"}
        Robust kernel on the measurement factors (IRLS weights at every linearization);
        odometry stays quadratic.
    robust_scale : float or None
        Kernel scale in Mahalanobis-distance units; None picks Huber 1.345, Cauchy 2.3849.
    outlier_probability : float or None
        After convergence, measurements whose ``e^T Q^-1 e`` exceeds this chi-square quantile
        (2 dof) are dropped and the problem is solved again (at most ``outlier_rounds``
        times); None keeps everything.
    outlier_rounds : int
        See ``outlier_probability``.
    motion_noise_floor : (float, float, float)
        Variance per second ``(m^2/s, m^2/s, rad^2/s)`` added to every step's process noise.
    keyframes : {"observations", "all"}
        Which steps carry a pose variable: those with observations (and the last), or all.
    solver : {"schur", "sparse", "reduced"}
        The linear solve of each iteration: ``"schur"`` (default) eliminates the poses, a
        banded chain, by banded Cholesky and solves the landmarks' dense Schur complement;
        ``"sparse"`` factors the whole system by sparse Cholesky (ordering and symbolic
        factorization once per problem, a numeric factor per iteration); ``"reduced"`` is the
        book's reduction onto the poses (Tables 11.3-11.4). All three give the same step.
    initialization : {"incremental", "dead_reckoning"}
        Start from Table 11.1's dead reckoning, or (default) from growing prefixes of the log
        solved one after the other, each extended by dead reckoning (see
        :func:`optimize_graphslam`).
    min_range : float
        Observations closer than this (m) are ignored, as in the EKF.
    covariances : bool
        Compute the marginal covariances of the result (poses of every step, landmarks).
    correspondence_probability : float
        Unknown correspondences (ids -1): chi-square gate (2 dof) of the correspondence test
        under which two landmark hypotheses are merged (Tables 11.8-11.9).
    association_probability, new_landmark_probability : float
        Unknown correspondences: the chi-square gates (2 dof) of the front end's
        maximum-likelihood association and of a new landmark (:func:`graphslam_associate`).
    min_observations : int
        Unknown correspondences: landmarks seen fewer times are dropped at the end.
    visibility_range, visibility_fov, max_misses
        Unknown correspondences, negative evidence (the EKF's rule for provisional landmarks,
        section 10.3.3, applied on the smoothed path): a landmark that is within
        ``visibility_range`` (m) and the field of view ``visibility_fov`` (rad, centred on the
        sensor's heading) of more than ``max_misses`` poses that do not see it before it has
        been seen ``min_observations`` times is dropped. None (default) turns it off.
    merge_radius : float
        Unknown correspondences: landmark pairs closer than this (m) are tested (Table 11.8).
    """

    max_iterations: int = 50
    relative_tolerance: float = 1e-10
    initial_lambda: float = 1e-9
    robust: GraphSLAMRobust = "none"
    robust_scale: float | None = None
    outlier_probability: float | None = None
    outlier_rounds: int = 3
    motion_noise_floor: tuple[float, float, float] = (1e-6, 1e-6, 1e-8)
    keyframes: Literal["observations", "all"] = "observations"
    solver: Literal["schur", "sparse", "reduced"] = "schur"
    initialization: Literal["incremental", "dead_reckoning"] = "incremental"
    min_range: float = 0.0
    covariances: bool = True
    correspondence_probability: float = 0.99
    association_probability: float = 0.99
    new_landmark_probability: float = 0.9999
    min_observations: int = 3
    merge_radius: float = 5.0
    visibility_range: float | None = None
    visibility_fov: float = 2 * math.pi
    max_misses: int = 3

    def __post_init__(self) -> None:
        require_integer("max_iterations", self.max_iterations, 0)
        if not (is_finite_number(self.relative_tolerance) and self.relative_tolerance >= 0):
            raise ValueError(
                f"relative_tolerance must be a finite number >= 0, got {self.relative_tolerance}"
            )
        if not (is_finite_number(self.initial_lambda) and self.initial_lambda >= 0):
            raise ValueError(
                f"initial_lambda must be a finite number >= 0, got {self.initial_lambda}"
            )
        if self.robust not in _DEFAULT_SCALE:
            raise ValueError(f"robust must be one of {sorted(_DEFAULT_SCALE)}, got {self.robust!r}")
        if self.robust_scale is None:
            object.__setattr__(self, "robust_scale", _DEFAULT_SCALE[self.robust])
        elif not (is_finite_number(self.robust_scale) and self.robust_scale > 0):
            raise ValueError(f"robust_scale must be a positive number, got {self.robust_scale}")
        if self.outlier_probability is not None and not (
            is_finite_number(self.outlier_probability) and 0 < self.outlier_probability < 1
        ):
            raise ValueError(
                f"outlier_probability must lie in (0, 1), got {self.outlier_probability}"
            )
        require_integer("outlier_rounds", self.outlier_rounds, 0)
        floor = tuple(self.motion_noise_floor)
        if len(floor) != 3 or not all(is_finite_number(v) and v >= 0 for v in floor):
            raise ValueError(
                f"motion_noise_floor must be 3 finite numbers >= 0, got {self.motion_noise_floor}"
            )
        object.__setattr__(self, "motion_noise_floor", tuple(float(v) for v in floor))
        if self.keyframes not in ("observations", "all"):
            raise ValueError(f"keyframes must be 'observations' or 'all', got {self.keyframes!r}")
        if self.solver not in ("schur", "sparse", "reduced"):
            raise ValueError(f"solver must be 'schur', 'sparse' or 'reduced', got {self.solver!r}")
        if self.initialization not in ("incremental", "dead_reckoning"):
            raise ValueError(
                "initialization must be 'incremental' or 'dead_reckoning', got "
                f"{self.initialization!r}"
            )
        if not (
            is_finite_number(self.correspondence_probability)
            and 0 < self.correspondence_probability < 1
        ):
            raise ValueError(
                "correspondence_probability must lie in (0, 1), got "
                f"{self.correspondence_probability}"
            )
        if not (is_finite_number(self.min_range) and self.min_range >= 0):
            raise ValueError(f"min_range must be a finite number >= 0, got {self.min_range}")
        if not (
            is_finite_number(self.association_probability)
            and is_finite_number(self.new_landmark_probability)
            and 0 < self.association_probability <= self.new_landmark_probability < 1
        ):
            raise ValueError(
                "need 0 < association_probability <= new_landmark_probability < 1, got "
                f"{self.association_probability} and {self.new_landmark_probability}"
            )
        require_integer("min_observations", self.min_observations, 1)
        if not (is_finite_number(self.merge_radius) and self.merge_radius > 0):
            raise ValueError(f"merge_radius must be a positive number, got {self.merge_radius}")
        if self.visibility_range is not None and not (
            is_finite_number(self.visibility_range) and self.visibility_range > 0
        ):
            raise ValueError(
                f"visibility_range must be a positive number or None, got {self.visibility_range}"
            )
        if not (is_finite_number(self.visibility_fov) and self.visibility_fov > 0):
            raise ValueError(f"visibility_fov must be a positive number, got {self.visibility_fov}")
        require_integer("max_misses", self.max_misses, 0)

    @property
    def scale(self) -> float:
        """The resolved robust scale."""
        assert self.robust_scale is not None  # resolved in __post_init__
        return float(self.robust_scale)


# --------------------------------------------------------------------------------- the problem
@dataclass(frozen=True, eq=False)
class GraphSLAMProblem:
    """A recorded log as GraphSLAM sees it (arrays; build one with :func:`segment_log`).

    Attributes
    ----------
    motion_model, measurement_model
        As for :class:`~probmap.slam.landmark.ekf.EKFSLAM`.
    prior_mean : ndarray, shape (3,)
        ``mu_0`` of the anchoring prior on the first pose.
    prior_information : ndarray, shape (3, 3)
        ``Omega_0`` (inverse of the initial covariance).
    controls : ndarray, shape (T, 2)
    dts : ndarray, shape (T,)
        Control and length (s) of every step.
    seg_ptr : ndarray of int64, shape (K,)
        Segment ``s`` (node ``s`` to node ``s + 1``) holds steps ``seg_ptr[s] ..
        seg_ptr[s + 1] - 1``; ``K`` pose nodes, node 0 the initial pose.
    step_node : ndarray of int64, shape (T,)
        The node whose pose a step's observations were taken from.
    obs_node, obs_landmark : ndarray of int64, shape (k,)
        Node and landmark slot of every observation.
    z : ndarray, shape (k, 2)
        Observations ``(range, bearing)``.
    landmark_ids : ndarray of int64, shape (L,)
        Landmark id of every slot.
    """

    motion_model: Any
    measurement_model: Any
    prior_mean: FloatArray
    prior_information: FloatArray
    controls: FloatArray
    dts: FloatArray
    seg_ptr: IntArray
    step_node: IntArray
    obs_node: IntArray
    obs_landmark: IntArray
    z: FloatArray
    landmark_ids: IntArray

    @property
    def n_nodes(self) -> int:
        """Pose variables ``K``."""
        return int(self.seg_ptr.size)

    @property
    def n_landmarks(self) -> int:
        """Landmark variables ``L``."""
        return int(self.landmark_ids.size)


def segment_log(
    dts: ArrayLike, n_obs: ArrayLike, keyframes: str = "observations"
) -> tuple[IntArray, IntArray]:
    """Which steps carry a pose variable, and which node each step's observations belong to.

    A step ends a node when time has passed since the last node and it has observations (or it
    is the last step, or ``keyframes == "all"``). Observations at a step with no motion since
    the last node belong to that node.

    Parameters
    ----------
    dts : array_like, shape (T,)
        Step lengths (s), >= 0.
    n_obs : array_like of int, shape (T,)
        Observations per step.
    keyframes : {"observations", "all"}

    Returns
    -------
    seg_ptr : ndarray of int64, shape (K,)
        ``seg_ptr[0] = 0`` and ``seg_ptr[s + 1]`` one past the step that ends node ``s + 1``.
    step_node : ndarray of int64, shape (T,)
    """
    d = np.asarray(dts, dtype=np.float64)
    nz = np.asarray(n_obs, dtype=np.int64)
    T = d.size
    every = keyframes == "all"
    ptr = [0]
    step_node = np.empty(T, dtype=np.int64)
    cur = 0
    elapsed = 0.0
    for t in range(T):
        elapsed += d[t]
        if elapsed > 0.0 and (every or nz[t] > 0 or t == T - 1):
            cur += 1
            ptr.append(t + 1)
            elapsed = 0.0
        step_node[t] = cur
    return np.asarray(ptr, dtype=np.int64), step_node


# ------------------------------------------------------------------------------ motion chain
def _model_params(model: Any) -> tuple[int, FloatArray] | None:
    """Kernel id and parameters of the package's motion models; None for any other model."""
    if type(model) is VelocityModel:
        ref = -1.0 if model.reference_dt is None else float(model.reference_dt)
        return _k.KIND_VELOCITY, np.array([*model.alphas, model.sigma_v, model.sigma_w, ref])
    if type(model) is AckermannModel:
        ref = -1.0 if model.reference_dt is None else float(model.reference_dt)
        a, b = model.reference_point
        p = [model.wheelbase, model.encoder_offset, a, b, model.sigma_v, model.sigma_steer, ref]
        return _k.KIND_ACKERMANN, np.array(p, dtype=np.float64)
    return None


@dataclass(frozen=True, eq=False)
class _Chain:
    xbar: FloatArray  # (n, 3) predicted pose after each step, from its segment's start node
    Phi: FloatArray  # (n, 3, 3) d xbar / d start node
    Sig: FloatArray  # (n, 3, 3) accumulated process covariance
    G: FloatArray  # (n, 3, 3) the step's Jacobian


def motion_chain(
    problem: GraphSLAMProblem,
    X: FloatArray,
    floor: tuple[float, float, float],
    *,
    propagate: bool = False,
) -> _Chain:
    """The motion model chained over every segment from its start node (Table 11.2 lines 4-8,
    steps between two nodes composed): per step the prediction, ``d / d x_start``, and the
    process covariance accumulated since the start node. With ``propagate`` each segment's
    end is written into ``X`` first (dead reckoning). Compiled for the package's velocity and
    Ackermann models; any other model with ``predict`` and ``control_covariance`` runs in
    Python.
    """
    n = int(problem.seg_ptr[-1])
    xbar = np.empty((n, 3))
    Phi = np.empty((n, 3, 3))
    Sig = np.empty((n, 3, 3))
    Gs = np.empty((n, 3, 3))
    fl = np.asarray(floor, dtype=np.float64)
    kp = _model_params(problem.motion_model)
    if kp is not None:
        status = _k.chain_steps(
            kp[0], kp[1], X, problem.controls, problem.dts, problem.seg_ptr, fl, propagate,
            xbar, Phi, Sig, Gs,
        )  # fmt: skip
        if status != _k.STATUS_OK:
            raise ValueError("a steering angle makes the encoder speed conversion singular")
        return _Chain(xbar, Phi, Sig, Gs)
    model = problem.motion_model
    ptr = problem.seg_ptr
    eye = np.eye(3)
    for s in range(ptr.size - 1):
        x = X[s].copy()
        F = eye.copy()
        S = np.zeros((3, 3))
        for t in range(int(ptr[s]), int(ptr[s + 1])):
            dt = float(problem.dts[t])
            G = eye
            if dt > 0:
                u = problem.controls[t]
                x, G, V = model.predict(x, u, dt)
                M = model.control_covariance(u, dt)
                S = G @ S @ G.T + V @ M @ V.T + np.diag(fl * dt)
                F = G @ F
            xbar[t], Phi[t], Sig[t], Gs[t] = x, F, S, G
        if propagate:
            X[s + 1] = x
    return _Chain(xbar, Phi, Sig, Gs)


def _measurements(
    model: Any, X: FloatArray, Lm: FloatArray, node: IntArray, lm: IntArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``z_hat (k, 2)``, ``H_x (k, 2, 3)``, ``H_m (k, 2, 2)`` of every observation."""
    k = node.size
    if type(model) is RangeBearingModel:
        return _range_bearing(model, X[node], Lm[lm])
    zh = np.empty((k, 2))
    Hx = np.empty((k, 2, 3))
    Hm = np.empty((k, 2, 2))
    if k == 0:
        return zh, Hx, Hm
    cut = np.flatnonzero(np.diff(node)) + 1
    for a, b in zip(np.r_[0, cut], np.r_[cut, k], strict=True):
        zh[a:b], Hx[a:b], Hm[a:b] = model.predict_many(X[node[a]], Lm[lm[a:b]])
    return zh, Hx, Hm


def _range_bearing(
    model: RangeBearingModel, poses: FloatArray, m: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:meth:`RangeBearingModel.predict_many` for one pose per landmark (the same equations,
    batched over observations; checked against the model in the tests)."""
    dx, dy, dth = model.sensor_offset
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    sx = poses[:, 0] + c * dx - s * dy
    sy = poses[:, 1] + s * dx + c * dy
    dsx = -s * dx - c * dy
    dsy = c * dx - s * dy
    d0 = m[:, 0] - sx
    d1 = m[:, 1] - sy
    q = d0 * d0 + d1 * d1
    if np.any(q <= 1e-18):
        raise ValueError("a landmark coincides with the sensor position (zero range)")
    r = np.sqrt(q)
    k = poses.shape[0]
    z = np.empty((k, 2))
    z[:, 0] = r
    z[:, 1] = wrap_angle(np.arctan2(d1, d0) - poses[:, 2] - dth)
    Hm = np.empty((k, 2, 2))
    Hm[:, 0, 0] = d0 / r
    Hm[:, 0, 1] = d1 / r
    Hm[:, 1, 0] = -d1 / q
    Hm[:, 1, 1] = d0 / q
    Hx = np.empty((k, 2, 3))
    Hx[:, :, 0] = -Hm[:, :, 0]
    Hx[:, :, 1] = -Hm[:, :, 1]
    Hx[:, :, 2] = -(Hm[:, :, 0] * dsx[:, None] + Hm[:, :, 1] * dsy[:, None])
    Hx[:, 1, 2] -= 1.0
    return z, Hx, Hm


# -------------------------------------------------------------------------- Table 11.1
def graphslam_initialize(
    problem: GraphSLAMProblem, floor: tuple[float, float, float] = (1e-6, 1e-6, 1e-8)
) -> tuple[FloatArray, FloatArray]:
    """Initial guess (Table 11.1): dead-reckoned poses from ``mu_0``, and every landmark at
    its first sighting through the inverse measurement model (as Table 11.2 does for a
    landmark not seen before).

    Returns
    -------
    X : ndarray, shape (K, 3)
        Node poses.
    Lm : ndarray, shape (L, 2)
        Landmark positions.
    """
    X = np.zeros((problem.n_nodes, 3))
    X[0] = problem.prior_mean
    motion_chain(problem, X, floor, propagate=True)
    Lm = np.zeros((problem.n_landmarks, 2))
    seen = np.zeros(problem.n_landmarks, dtype=bool)
    inv = problem.measurement_model.inverse
    for k in range(problem.obs_landmark.size):
        j = int(problem.obs_landmark[k])
        if not seen[j]:
            Lm[j] = inv(X[problem.obs_node[k]], problem.z[k])[0]
            seen[j] = True
    return X, Lm


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


# ------------------------------------------------------------------ Tables 11.8-11.9
def landmark_joint_covariance(H: sp.spmatrix, n_pose_vars: int) -> FloatArray:
    """The joint marginal covariance ``Sigma_mm`` (2L, 2L) of all landmarks: the landmark rows
    of ``H^-1``, from one sparse factorization and ``2L`` solves (small maps only)."""
    Hc = sp.csc_matrix(H)
    n = Hc.shape[0]
    m = n - n_pose_vars
    if m == 0:
        return np.zeros((0, 0))
    lu = splu(
        Hc, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
    )
    E = np.zeros((n, m))
    E[n_pose_vars + np.arange(m), np.arange(m)] = 1.0
    Sm = np.asarray(lu.solve(E), dtype=np.float64)[n_pose_vars:]
    return 0.5 * (Sm + Sm.T)


def graphslam_correspondence_test(
    landmarks: FloatArray, joint_covariance: FloatArray, pairs: IntArray
) -> tuple[FloatArray, FloatArray]:
    """The correspondence test of Table 11.8 for landmark pairs ``(j, k)``.

    The book marginalizes everything but ``m_j, m_k`` (lines 2-3), maps them to the difference
    ``Delta = m_j - m_k`` (lines 4-6) and returns the Gaussian density of ``Delta = 0``
    (line 7). In moments: ``Delta ~ N(mu_j - mu_k, Sigma_jj + Sigma_kk - Sigma_jk - Sigma_kj)``.

    Parameters
    ----------
    landmarks : ndarray, shape (L, 2)
    joint_covariance : ndarray, shape (2L, 2L)
        :func:`landmark_joint_covariance`.
    pairs : ndarray of int, shape (P, 2)

    Returns
    -------
    d2 : ndarray, shape (P,)
        ``mu_Delta^T Sigma_Delta^-1 mu_Delta`` (chi-square, 2 dof, when ``j`` and ``k`` are one
        landmark).
    probability : ndarray, shape (P,)
        ``|2 pi Sigma_Delta|^-1/2 exp(-d2 / 2)``, the book's value.
    """
    pr = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    j, k = pr[:, 0], pr[:, 1]
    C = joint_covariance.reshape(landmarks.shape[0], 2, landmarks.shape[0], 2)
    S = C[j, :, j, :] + C[k, :, k, :] - C[j, :, k, :] - C[k, :, j, :]
    d = landmarks[j] - landmarks[k]
    det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
    det = np.maximum(det, 1e-300)
    d2 = S[:, 1, 1] * d[:, 0] ** 2 - 2 * S[:, 0, 1] * d[:, 0] * d[:, 1] + S[:, 0, 0] * d[:, 1] ** 2
    d2 = d2 / det
    return d2, np.exp(-0.5 * d2) / (2 * np.pi * np.sqrt(det))


def _merge_pass(
    problem: GraphSLAMProblem, Lm: FloatArray, Sigma_mm: FloatArray, gate: float
) -> IntArray | None:
    """One round of Table 11.9's merges: landmark pairs passing the correspondence test, most
    likely first, joined unless the two were seen from one pose (two observations at one time
    are two landmarks). Returns the new slot of every landmark, or None when nothing merges.
    (Merging each hypothesis at most once per round, so that every merge is re-solved first,
    stalled with more duplicates left on simulation.)"""
    from scipy.spatial import cKDTree

    L = Lm.shape[0]
    if L < 2:
        return None
    sd = np.sqrt(np.maximum(np.diagonal(Sigma_mm).reshape(L, 2).max(axis=1), 0.0))
    radius = float(np.sqrt(gate) * 2.0 * sd.max()) + 1e-9
    pairs = np.array(sorted(cKDTree(Lm).query_pairs(radius)), dtype=np.int64).reshape(-1, 2)
    if pairs.size == 0:
        return None
    d2, _ = graphslam_correspondence_test(Lm, Sigma_mm, pairs)
    ok = d2 < gate
    pairs, d2 = pairs[ok], d2[ok]
    if pairs.size == 0:
        return None
    nodes: list[set[int]] = [set() for _ in range(L)]
    for n, j in zip(problem.obs_node, problem.obs_landmark, strict=True):
        nodes[int(j)].add(int(n))
    return _join_most_likely_first(pairs, d2, nodes)


def _join_most_likely_first(
    pairs: IntArray, d2: FloatArray, nodes: list[set[int]]
) -> IntArray | None:
    """Join the landmark ``pairs`` (P, 2) that passed the correspondence test, smallest
    Mahalanobis distance ``d2`` first (union-find), unless the two groups were seen from one
    pose (``nodes[j]``: the poses that observed landmark ``j``; two observations at one time
    are two landmarks). Returns the new slot of each of the ``len(nodes)`` landmarks, or None
    when nothing was joined. ``nodes`` is updated in place."""
    parent = np.arange(len(nodes))

    def root(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = int(parent[a])
        return a

    merged = False
    for a, b in pairs[np.argsort(d2)]:
        ra, rb = root(int(a)), root(int(b))
        if ra == rb or nodes[ra] & nodes[rb]:
            continue
        parent[rb] = ra
        nodes[ra] |= nodes[rb]
        merged = True
    if not merged:
        return None
    roots = np.array([root(i) for i in range(len(nodes))])
    _, slot = np.unique(roots, return_inverse=True)
    return slot.astype(np.int64)


def optimize_graphslam_unknown(
    problem: GraphSLAMProblem,
    config: GraphSLAMConfig | None = None,
    *,
    correspondence_probability: float = 0.99,
    max_rounds: int = 40,
    max_hypotheses: int = 4000,
) -> tuple[GraphSLAMResult, GraphSLAMProblem]:
    """GraphSLAM with unknown correspondences (Table 11.9): start from the given landmark
    hypotheses (e.g. one per observation), solve, merge the pairs that pass the correspondence
    test (Table 11.8) at the chi-square ``correspondence_probability`` gate, and repeat until
    nothing merges. Needs the joint landmark covariance, so it suits small maps (hundreds of
    hypotheses).

    Returns the final result and the problem with its merged landmark slots. More than
    ``max_hypotheses`` hypotheses raise ``ValueError`` (Victoria Park has 48,000): large logs
    take :func:`optimize_graphslam_front_end` instead (what :class:`GraphSLAM` runs).
    """
    cfg = config if config is not None else GraphSLAMConfig()
    if problem.n_landmarks > max_hypotheses:
        raise ValueError(
            f"{problem.n_landmarks:,} landmark hypotheses are too many for GraphSLAM's unknown-"
            f"correspondence loop (its joint covariance; at most {max_hypotheses:,}): give "
            "landmark ids, or use the EKF or SEIF on this log"
        )
    gate = _chi2_gate_2dof(correspondence_probability)
    res = optimize_graphslam(problem, cfg)
    for _ in range(max_rounds):
        sysm = graphslam_linearize(problem, res.nodes, res.landmarks, cfg)
        Sigma_mm = landmark_joint_covariance(sysm.H, sysm.n_pose_vars)
        slot = _merge_pass(problem, res.landmarks, Sigma_mm, gate)
        if slot is None:
            break
        from dataclasses import replace

        n_new = int(slot.max()) + 1
        Lm = np.zeros((n_new, 2))
        np.add.at(Lm, slot, res.landmarks)
        Lm /= np.bincount(slot, minlength=n_new)[:, None]
        problem = replace(
            problem,
            obs_landmark=slot[problem.obs_landmark],
            landmark_ids=np.arange(n_new, dtype=np.int64),
        )
        res = optimize_graphslam(problem, cfg, initial=(res.nodes, Lm))
    return res, problem


# --------------------------------------------------------------- unknown correspondences
def _body_increments(
    problem: GraphSLAMProblem, floor: tuple[float, float, float]
) -> tuple[FloatArray, FloatArray]:
    """Every segment's motion ``d (S, 3)`` and its noise ``Sigma (S, 3, 3)`` in the frame of its
    start node (the models move in the robot frame, so these do not depend on the start pose)."""
    K = problem.n_nodes
    ch = motion_chain(problem, np.zeros((K, 3)), floor)
    end = problem.seg_ptr[1:] - 1
    return ch.xbar[end], ch.Sig[end]


def graphslam_associate(
    problem: GraphSLAMProblem,
    *,
    gate_probability: float = 0.99,
    new_landmark_probability: float = 0.9999,
    floor: tuple[float, float, float] = (1e-6, 1e-6, 1e-8),
) -> tuple[IntArray, FloatArray, FloatArray]:
    """Initial correspondences for GraphSLAM (the front end of Table 11.9's loop).

    The poses are walked in order along the odometry (the segments' motion and noise); at each
    pose its observations are associated by maximum likelihood with Mahalanobis gating
    (:func:`~probmap.slam.landmark.association.associate_ml`, Table 10.2 lines 16-18) against the
    landmarks mapped so far, with ``S = H_x P H_x^T + H_m P_m H_m^T + Q`` from the pose's and each
    landmark's own covariance. The matched ones correct the pose and those landmarks together
    (one EKF update of the pose and the few landmarks involved, Table 10.1 lines 12-18, their
    cross-covariances with everything else ignored, which keeps a step O(1) in the map size);
    an observation beyond the ``new_landmark_probability`` gate of every landmark starts a new
    one (inverse measurement model), and one between the gates is left out. Ignoring the
    cross-covariances makes the estimate overconfident after a long loop, so a revisited tree
    may come back as a second landmark: the correspondence test of Table 11.8 merges those
    after the batch solve (:func:`optimize_graphslam_unknown`).

    Parameters
    ----------
    problem : GraphSLAMProblem
        Its ``obs_landmark`` is ignored.
    gate_probability, new_landmark_probability : float
        Chi-square probabilities (2 dof) of the acceptance and new-landmark gates.
    floor : (3,) float
        The motion noise floor (variance per second), as in :class:`GraphSLAMConfig`.

    Returns
    -------
    slot : ndarray of int64, shape (k,)
        Landmark of every observation, or -1 for one left out.
    X : ndarray, shape (K, 3)
        The front end's pose of every node.
    Lm : ndarray, shape (L, 2)
        Its landmarks (``L = slot.max() + 1``).
    """
    if not 0 < gate_probability <= new_landmark_probability < 1:
        raise ValueError("need 0 < gate_probability <= new_landmark_probability < 1")
    gate = _chi2_gate_2dof(gate_probability)
    new_gate = _chi2_gate_2dof(new_landmark_probability)
    K = problem.n_nodes
    model = problem.measurement_model
    if K > 1:
        d, Sig = _body_increments(problem, floor)
    else:
        d, Sig = np.zeros((0, 3)), np.zeros((0, 3, 3))
    if type(model) is not RangeBearingModel:
        return _associate_python(problem, gate, new_gate, d, Sig)
    n_obs = problem.z.shape[0]
    slot = np.full(n_obs, -1, dtype=np.int64)
    X = np.zeros((K, 3))
    Lm = np.zeros((max(n_obs, 1), 2))
    Pm = np.zeros((max(n_obs, 1), 2, 2))
    L = _k.associate_front_end(
        np.asarray(problem.prior_mean, dtype=np.float64).copy(),
        np.linalg.inv(problem.prior_information),
        np.ascontiguousarray(d),
        np.ascontiguousarray(Sig),
        np.searchsorted(problem.obs_node, np.arange(K + 1)).astype(np.int64),
        np.ascontiguousarray(problem.z, dtype=np.float64),
        np.asarray(model.sensor_offset, dtype=np.float64),
        np.ascontiguousarray(model.R, dtype=np.float64),
        float(gate),
        float(new_gate),
        _reach(problem),
        slot,
        X,
        Lm,
        Pm,
    )
    if L < 0:
        raise ValueError("a landmark coincides with the sensor position (zero range)")
    return slot, X, Lm[:L].copy()


def _reach(problem: GraphSLAMProblem) -> float:
    """Landmarks farther than this from the robot (m) are not candidates for association."""
    return float(problem.z[:, 0].max()) + 5.0 if problem.z.shape[0] else 0.0


def _associate_python(
    problem: GraphSLAMProblem, gate: float, new_gate: float, d: FloatArray, Sig: FloatArray
) -> tuple[IntArray, FloatArray, FloatArray]:
    """:func:`graphslam_associate` for any measurement model with ``predict_many`` and
    ``inverse`` (and the reference of its compiled kernel in the tests)."""
    from probmap.slam.landmark.association import NEW, associate_ml

    K = problem.n_nodes
    model = problem.measurement_model
    Q = np.asarray(model.R, dtype=np.float64)
    n_obs = problem.z.shape[0]
    slot = np.full(n_obs, -1, dtype=np.int64)
    X = np.zeros((K, 3))
    Lm = np.zeros((max(n_obs, 1), 2))
    Pm = np.zeros((max(n_obs, 1), 2, 2))
    L = 0
    x = np.asarray(problem.prior_mean, dtype=np.float64).copy()
    P = np.linalg.inv(problem.prior_information)
    obs_ptr = np.searchsorted(problem.obs_node, np.arange(K + 1))
    reach = _reach(problem)
    for s in range(K):
        if s > 0:  # predict along the segment: x <- x (+) d, P <- F P F^T + Rt^T Sigma Rt
            c, sn = math.cos(x[2]), math.sin(x[2])
            dx, dy = d[s - 1, 0], d[s - 1, 1]
            F = np.eye(3)
            F[0, 2] = -sn * dx - c * dy
            F[1, 2] = c * dx - sn * dy
            Rw = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
            x = np.array([x[0] + c * dx - sn * dy, x[1] + sn * dx + c * dy, x[2] + d[s - 1, 2]])
            x[2] = wrap_angle(x[2])
            P = F @ P @ F.T + Rw @ Sig[s - 1] @ Rw.T
        a, b = int(obs_ptr[s]), int(obs_ptr[s + 1])
        if b > a:
            z = problem.z[a:b]
            k = b - a
            if L:
                near = np.flatnonzero(np.hypot(Lm[:L, 0] - x[0], Lm[:L, 1] - x[1]) < reach)
            else:
                near = np.zeros(0, dtype=np.int64)
            if near.size:
                zh, Hx, Hm = _measurements(
                    model, x[None, :], Lm[near], np.zeros(near.size, np.int64), np.arange(near.size)
                )
                S = Hx @ P @ Hx.transpose(0, 2, 1) + Hm @ Pm[near] @ Hm.transpose(0, 2, 1) + Q
                match = associate_ml(z, zh, S, gate=gate, new_gate=new_gate).match
            else:
                match = np.full(k, NEW, dtype=np.int64)
            hit = np.flatnonzero(match >= 0)
            if hit.size:  # one EKF update of the pose and the matched landmarks
                js = near[match[hit]]
                m = hit.size
                n = 3 + 2 * m
                mu = np.concatenate([x, Lm[js].ravel()])
                C = np.zeros((n, n))
                C[:3, :3] = P
                for q, j in enumerate(js):
                    C[3 + 2 * q : 5 + 2 * q, 3 + 2 * q : 5 + 2 * q] = Pm[j]
                zh, Hx, Hm = _measurements(
                    model, x[None, :], Lm[js], np.zeros(m, np.int64), np.arange(m)
                )
                H = np.zeros((2 * m, n))
                for q in range(m):
                    H[2 * q : 2 * q + 2, :3] = Hx[q]
                    H[2 * q : 2 * q + 2, 3 + 2 * q : 5 + 2 * q] = Hm[q]
                nu = z[hit] - zh
                nu[:, 1] = wrap_angle(nu[:, 1])
                HC = H @ C
                Sfull = HC @ H.T + np.kron(np.eye(m), Q)
                Kg = np.linalg.solve(Sfull, HC).T
                mu = mu + Kg @ nu.ravel()
                C = C - Kg @ HC
                C = 0.5 * (C + C.T)
                x = mu[:3].copy()
                x[2] = wrap_angle(x[2])
                P = C[:3, :3].copy()
                Lm[js] = mu[3:].reshape(m, 2)
                for q, j in enumerate(js):
                    Pm[j] = C[3 + 2 * q : 5 + 2 * q, 3 + 2 * q : 5 + 2 * q]
                slot[a + hit] = js
            for i in np.flatnonzero(match == NEW):
                xy, Jx, Jz = model.inverse(x, z[i])
                Lm[L] = xy
                Pm[L] = Jx @ P @ Jx.T + Jz @ Q @ Jz.T
                slot[a + i] = L
                L += 1
        X[s] = x
    return slot, X, Lm[:L].copy()


def landmark_pair_covariances(H: sp.spmatrix, n_pose_vars: int, landmarks: IntArray) -> FloatArray:
    """The joint marginal covariance of a few landmarks (the rows and columns of ``H^-1`` for
    ``landmarks``): one sparse factorization of ``H`` and ``2 m`` solves, so it scales to large
    maps where :func:`landmark_joint_covariance` (all ``2L`` columns) does not.

    Parameters
    ----------
    H : scipy.sparse matrix, shape (n, n)
        The information matrix at the solution.
    n_pose_vars : int
    landmarks : ndarray of int, shape (m,)
        Landmark slots.

    Returns
    -------
    ndarray, shape (2m, 2m)
        ``Cov(m_landmarks[0], m_landmarks[1], ...)``, landmark ``i`` at rows ``2i, 2i + 1``.
    """
    lm = np.asarray(landmarks, dtype=np.int64).reshape(-1)
    if lm.size == 0:
        return np.zeros((0, 0))
    Hc = sp.csc_matrix(H)
    n = Hc.shape[0]
    rows = (n_pose_vars + 2 * lm[:, None] + np.arange(2)).ravel()
    try:
        lu = splu(
            Hc, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
        )
    except RuntimeError as exc:
        raise ValueError(f"the information matrix is singular ({exc})") from exc
    C = np.empty((rows.size, rows.size))
    for a in range(0, rows.size, 128):  # columns in chunks: (n, 128) at a time, not (n, 2m)
        cols = rows[a : a + 128]
        E = np.zeros((n, cols.size))
        E[cols, np.arange(cols.size)] = 1.0
        C[:, a : a + cols.size] = np.asarray(lu.solve(E), dtype=np.float64)[rows]
    return 0.5 * (C + C.T)


def _merge_candidates(
    problem: GraphSLAMProblem,
    Lm: FloatArray,
    H: sp.spmatrix,
    n_pose_vars: int,
    gate: float,
    radius: float,
) -> IntArray | None:
    """Table 11.9's merges at scale: candidate pairs are the landmarks closer than ``radius``
    (a KD-tree), tested with :func:`graphslam_correspondence_test` on the joint covariance of
    the landmarks involved (:func:`landmark_pair_covariances`), and joined most likely first
    unless the two were seen from one pose. Returns the new slot of every landmark, or None."""
    from scipy.spatial import cKDTree

    L = Lm.shape[0]
    if L < 2:
        return None
    pairs = np.array(sorted(cKDTree(Lm).query_pairs(radius)), dtype=np.int64).reshape(-1, 2)
    if pairs.size == 0:
        return None
    # two landmarks seen from one pose are two trees: no test needed
    order = np.argsort(problem.obs_landmark, kind="stable")
    ptr = np.searchsorted(problem.obs_landmark[order], np.arange(L + 1))
    nodes = [problem.obs_node[order[ptr[j] : ptr[j + 1]]] for j in range(L)]
    apart = np.array([np.intersect1d(nodes[a], nodes[b]).size == 0 for a, b in pairs], dtype=bool)
    pairs = pairs[apart]
    if pairs.size == 0:
        return None
    used, inv = np.unique(pairs, return_inverse=True)
    C = landmark_pair_covariances(H, n_pose_vars, used)
    d2, _ = graphslam_correspondence_test(Lm[used], C, inv.reshape(-1, 2))
    ok = d2 < gate
    pairs, d2 = pairs[ok], d2[ok]
    if pairs.size == 0:
        return None
    return _join_most_likely_first(pairs, d2, [set(int(v) for v in nodes[j]) for j in range(L)])


def _relabel(
    problem: GraphSLAMProblem, slot: IntArray, keep_obs: BoolArray | None = None
) -> GraphSLAMProblem:
    """``problem`` with observation ``i`` on landmark ``slot[obs_landmark[i]]`` (slots 0..n-1),
    keeping only ``keep_obs``."""
    from dataclasses import replace

    lm = slot[problem.obs_landmark]
    keep = np.ones(lm.size, dtype=bool) if keep_obs is None else keep_obs
    n = int(lm[keep].max()) + 1 if keep.any() else 0
    return replace(
        problem,
        obs_node=problem.obs_node[keep],
        z=problem.z[keep],
        obs_landmark=lm[keep].astype(np.int64),
        landmark_ids=np.arange(n, dtype=np.int64),
    )


def _mean_by_slot(Lm: FloatArray, slot: IntArray) -> FloatArray:
    n = int(slot.max()) + 1
    out = np.zeros((n, 2))
    np.add.at(out, slot, Lm)
    return out / np.bincount(slot, minlength=n)[:, None]


def _confirmed_before_misses(
    problem: GraphSLAMProblem, X: FloatArray, Lm: FloatArray, cfg: GraphSLAMConfig
) -> BoolArray:
    """Which landmarks reach ``min_observations`` sightings before more than ``max_misses``
    poses (after their first sighting) had them in view without seeing them: the EKF's
    provisional-landmark rule (section 10.3.3) replayed on the smoothed path. Only poses that
    observed something count (the scans)."""
    from scipy.spatial import cKDTree

    assert cfg.visibility_range is not None
    L = Lm.shape[0]
    ok = np.ones(L, dtype=bool)
    if L == 0:
        return ok
    scans = np.unique(problem.obs_node)
    dx, dy, dth = problem.measurement_model.sensor_offset
    c, s = np.cos(X[scans, 2]), np.sin(X[scans, 2])
    sensor = np.column_stack([X[scans, 0] + c * dx - s * dy, X[scans, 1] + s * dx + c * dy])
    near = cKDTree(sensor).query_ball_tree(cKDTree(Lm), float(cfg.visibility_range))
    node = np.repeat(scans, [len(v) for v in near])
    lm = np.fromiter((j for v in near for j in v), dtype=np.int64, count=node.size)
    d = Lm[lm] - sensor[np.searchsorted(scans, node)]
    bearing = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - X[node, 2] - dth)
    vis = np.abs(bearing) <= 0.5 * cfg.visibility_fov
    node, lm = node[vis], lm[vis]
    seen = set(zip(problem.obs_node.tolist(), problem.obs_landmark.tolist(), strict=True))
    first = np.full(L, np.iinfo(np.int64).max)
    np.minimum.at(first, problem.obs_landmark, problem.obs_node)
    # every (node, landmark) event after the first sighting, in time order: hit or miss
    after = node >= first[lm]
    node, lm = node[after], lm[after]
    hit = np.array(
        [(n, j) in seen for n, j in zip(node.tolist(), lm.tolist(), strict=True)], dtype=np.int64
    )
    order = np.lexsort((node, lm))
    lm, hit = lm[order], hit[order]
    need = int(cfg.min_observations)
    bounds = np.searchsorted(lm, np.arange(L + 1))
    for j in range(L):
        h = hit[bounds[j] : bounds[j + 1]]
        confirmed_at = np.flatnonzero(np.cumsum(h) >= need)
        stop = int(confirmed_at[0]) if confirmed_at.size else h.size
        if int((1 - h[:stop]).sum()) > cfg.max_misses:
            ok[j] = False
    return ok


def optimize_graphslam_front_end(
    problem: GraphSLAMProblem,
    config: GraphSLAMConfig | None = None,
    *,
    max_rounds: int = 10,
) -> tuple[GraphSLAMResult, GraphSLAMProblem]:
    """GraphSLAM with unknown correspondences on large logs (Table 11.9 from a front end).

    1. Initial correspondences and a starting point from :func:`graphslam_associate`
       (incremental maximum-likelihood association along the odometry, gates
       ``config.association_probability`` and ``config.new_landmark_probability``).
    2. The sparse batch solve (:func:`optimize_graphslam`, with the robust kernel and outlier
       rejection of ``config``).
    3. The correspondence test of Table 11.8 on the pairs of landmarks closer than
       ``config.merge_radius`` (a KD-tree, so the number of tests grows with the map, not its
       square; their joint covariance from :func:`landmark_pair_covariances`), merging those
       under the ``config.correspondence_probability`` gate; back to 2 until nothing merges
       (at most ``max_rounds`` times).
    4. Landmarks seen fewer than ``config.min_observations`` times are dropped with their
       observations (a landmark seen once is fitted exactly and tells nothing about the path;
       the EKF likewise reports a landmark only after ``accept_hits`` sightings) and the log is
       solved a last time, with covariances if ``config`` asks for them.

    Parameters
    ----------
    problem : GraphSLAMProblem
        Its ``obs_landmark`` and ``landmark_ids`` are ignored.
    config : GraphSLAMConfig, optional
    max_rounds : int
        Most merge rounds.

    Returns
    -------
    result : GraphSLAMResult
    problem : GraphSLAMProblem
        ``problem`` with the observations kept and their final landmark slots.
    """
    cfg = config if config is not None else GraphSLAMConfig()
    gate = _chi2_gate_2dof(cfg.correspondence_probability)
    slot, X, Lm = graphslam_associate(
        problem,
        gate_probability=cfg.association_probability,
        new_landmark_probability=cfg.new_landmark_probability,
        floor=cfg.motion_noise_floor,
    )
    from dataclasses import replace

    seen = slot >= 0
    prob = replace(problem, obs_landmark=np.maximum(slot, 0))
    prob = _relabel(prob, np.arange(max(Lm.shape[0], 1), dtype=np.int64), seen)
    # the Schur solver's dense (3K, 2L) block is O(K L) memory on a long log with a large map:
    # the iterations factor the sparse system instead (the same step)
    solver = "sparse" if cfg.solver == "schur" else cfg.solver
    cfg = _replace_cfg(cfg, solver=solver)
    inner = _replace_cfg(cfg, covariances=False)
    res = optimize_graphslam(prob, inner, initial=(X, Lm))
    for _ in range(max_rounds):
        lin = _Linearizer(prob, inner)
        sysm = lin.linearize(res.nodes, res.landmarks)
        new = _merge_candidates(
            prob, res.landmarks, sysm.H, sysm.n_pose_vars, gate, cfg.merge_radius
        )
        if new is None:
            break
        Lm = _mean_by_slot(res.landmarks, new)
        prob = _relabel(prob, new)
        res = optimize_graphslam(prob, inner, initial=(res.nodes, Lm))
    count = np.bincount(prob.obs_landmark, minlength=prob.n_landmarks)
    strong = count >= int(cfg.min_observations)
    if cfg.visibility_range is not None:
        strong &= _confirmed_before_misses(prob, res.nodes, res.landmarks, cfg)
    if not strong.all():
        new = np.cumsum(strong) - 1
        keep = strong[prob.obs_landmark]
        Lm = res.landmarks[strong]
        prob = _relabel(prob, new, keep)
    else:
        Lm = res.landmarks
    res = optimize_graphslam(prob, cfg, initial=(res.nodes, Lm))
    return res, prob


# ------------------------------------------------------------------------------ the class
@dataclass
class _Log:
    controls: list[FloatArray] = field(default_factory=list)
    dts: list[float] = field(default_factory=list)
    z: list[FloatArray] = field(default_factory=list)
    ids: list[IntArray] = field(default_factory=list)


class GraphSLAM:
    """GraphSLAM over a whole log (Probabilistic Robotics, chapter 11); known correspondences,
    or unknown ones (ids -1, :func:`optimize_graphslam_front_end`).

    It takes the steps of a log like an online estimator (:meth:`predict` then :meth:`update`
    per record), and solves the full-SLAM problem over all of them in :meth:`smooth` (called
    by :func:`probmap.pipelines.landmark_slam.run_landmark_slam` after the last step). Until
    then :attr:`pose` is the last smoothed pose (the initial pose before the first solve).

    Parameters
    ----------
    motion_model, measurement_model, initial_pose, initial_covariance
        As for :class:`~probmap.slam.landmark.ekf.EKFSLAM` (the same noise parameters).
        ``initial_covariance`` must be positive definite: its inverse anchors the first pose.
    config : GraphSLAMConfig, optional
    """

    # every landmark estimator's first four arguments (EKFSLAM, SEIFSlam): one way to build them.
    def __init__(
        self,
        motion_model: Any,
        measurement_model: Any,
        initial_pose: ArrayLike,
        initial_covariance: ArrayLike,
        config: GraphSLAMConfig | None = None,
    ) -> None:
        mu, P0 = validate_initial_state(initial_pose, initial_covariance)
        if np.linalg.eigvalsh(P0).min() <= 0:
            raise ValueError("initial_covariance must be symmetric positive definite")
        self.motion_model = motion_model
        self.measurement_model = measurement_model
        self.config = config if config is not None else GraphSLAMConfig()
        self._mu0 = mu
        self._P0 = P0
        self._log = _Log()
        self._result: GraphSLAMResult | None = None
        self._problem: GraphSLAMProblem | None = None
        self._unknown = False
        self.last_nis: float = np.nan
        self.last_nis_dof: int = 0

    # ------------------------------------------------------------------ recording
    def predict(self, u: ArrayLike, dt: float) -> None:
        """Record a step: control ``u`` (2,) held for ``dt`` s (>= 0)."""
        u = validate_control(u)
        if not (is_finite_number(dt) and float(dt) >= 0):
            raise ValueError(f"dt must be a finite number >= 0, got {dt}")
        self._log.controls.append(u.copy())
        self._log.dts.append(float(dt))
        self._log.z.append(np.zeros((0, 2)))
        self._log.ids.append(np.zeros(0, dtype=np.int64))

    def update(self, z: ArrayLike, ids: ArrayLike) -> None:
        """Record the observations ``z`` (k, 2) with landmark ``ids`` (k,) of the last step."""
        z, ids = validate_observations(z, ids)
        if z.shape[0] == 0:
            return
        if not self._log.dts:
            raise ValueError("update before the first predict: record a step first")
        if np.any(ids < 0) and np.any(ids >= 0):
            raise ValueError(
                "mix of known and unknown landmark ids in one log: give all ids or none"
            )
        keep = z[:, 0] > max(self.config.min_range, 1e-9)
        self._log.z[-1] = np.concatenate([self._log.z[-1], z[keep]])
        self._log.ids[-1] = np.concatenate([self._log.ids[-1], ids[keep]])
        self._result = None

    # ------------------------------------------------------------------ solving
    def problem(self) -> GraphSLAMProblem:
        """The recorded log as a :class:`GraphSLAMProblem`."""
        log = self._log
        T = len(log.dts)
        controls = np.array(log.controls, dtype=np.float64).reshape(T, 2)
        dts = np.array(log.dts, dtype=np.float64)
        n_obs = np.array([z.shape[0] for z in log.z], dtype=np.int64)
        seg_ptr, step_node = segment_log(dts, n_obs, self.config.keyframes)
        z = np.concatenate(log.z) if T else np.zeros((0, 2))
        ids = np.concatenate(log.ids) if T else np.zeros(0, dtype=np.int64)
        obs_node = np.repeat(step_node, n_obs)
        if ids.size and np.any(ids < 0) and np.any(ids >= 0):
            raise ValueError(
                "mix of known and unknown landmark ids in one log: give all ids or none"
            )
        if ids.size and ids[0] < 0:  # unknown: one landmark hypothesis per observation
            ids = np.arange(ids.size, dtype=np.int64)
            self._unknown = True
        landmark_ids, slot = np.unique(ids, return_inverse=True)
        return GraphSLAMProblem(
            motion_model=self.motion_model,
            measurement_model=self.measurement_model,
            prior_mean=self._mu0.copy(),
            prior_information=np.asarray(np.linalg.inv(self._P0), dtype=np.float64),
            controls=controls,
            dts=dts,
            seg_ptr=seg_ptr,
            step_node=step_node,
            obs_node=obs_node.astype(np.int64),
            obs_landmark=slot.astype(np.int64).reshape(-1),
            z=z.reshape(-1, 2),
            landmark_ids=landmark_ids.astype(np.int64),
        )

    def optimize(self) -> GraphSLAMResult:
        """Solve the whole recorded log (:func:`optimize_graphslam`)."""
        if self._result is None:
            self._problem = self.problem()
            if self._unknown:
                self._result, self._problem = optimize_graphslam_front_end(
                    self._problem, self.config
                )
            else:
                self._result = optimize_graphslam(self._problem, self.config)
        return self._result

    def smooth(self) -> tuple[FloatArray, FloatArray]:
        """Solve, and return the pose (T, 3) and its marginal covariance (T, 3, 3) after every
        recorded step (zeros if ``config.covariances`` is off)."""
        r = self.optimize()
        covs = r.step_covariances
        if covs is None:
            covs = np.zeros((r.step_poses.shape[0], 3, 3))
        return r.step_poses.copy(), covs.copy()

    # ------------------------------------------------------------------ state access
    def state_nbytes(self) -> int:
        """Bytes of the recorded log and, once solved, of the problem's arrays and solution
        (the batch estimator's state; the information matrix is rebuilt per iteration)."""
        log = self._log
        total = sum(a.nbytes for a in log.controls) + 8 * len(log.dts)
        total += sum(a.nbytes for a in log.z) + sum(a.nbytes for a in log.ids)
        for obj in (self._problem, self._result):
            if obj is not None:
                total += sum(v.nbytes for v in vars(obj).values() if isinstance(v, np.ndarray))
        return int(total)

    @property
    def result(self) -> GraphSLAMResult | None:
        """The last solution (None before :meth:`optimize`)."""
        return self._result

    @property
    def pose(self) -> FloatArray:
        """Last smoothed pose (3,); the initial pose before the first solve."""
        if self._result is None or self._result.step_poses.shape[0] == 0:
            return self._mu0.copy()
        return self._result.step_poses[-1].copy()

    @property
    def pose_covariance(self) -> FloatArray:
        """Marginal covariance (3, 3) of :attr:`pose`."""
        r = self._result
        if r is None or r.step_covariances is None or r.step_covariances.shape[0] == 0:
            return self._P0.copy()
        return r.step_covariances[-1].copy()

    def landmarks(self) -> tuple[IntArray, FloatArray, FloatArray]:
        """Mapped landmarks after solving: ``ids (n,)``, ``xy (n, 2)``, ``cov (n, 2, 2)``."""
        r = self.optimize()
        assert self._problem is not None
        cov = r.landmark_covariances
        if cov is None:
            cov = np.zeros((r.landmarks.shape[0], 2, 2))
        return self._problem.landmark_ids.copy(), r.landmarks.copy(), cov.copy()


def build_graphslam(dataset: Any, config: GraphSLAMConfig | None = None) -> GraphSLAM:
    """A :class:`GraphSLAM` for a landmark dataset (its models and initial pose)."""
    return GraphSLAM(
        dataset.motion_model,
        dataset.measurement_model,
        dataset.initial_pose,
        dataset.initial_covariance,
        config,
    )
