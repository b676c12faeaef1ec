"""The GraphSLAM problem: configuration, the recorded log as arrays, the motion chain and
the measurement model, and the initialization of Table 11.1 (Probabilistic Robotics, ch. 11).

:class:`GraphSLAMConfig` holds every setting; :func:`segment_log` picks the steps that carry a
pose variable and :class:`GraphSLAMProblem` is the log as GraphSLAM sees it. :func:`motion_chain`
chains the motion model over the steps of each segment (one factor per segment, with its
prediction, Jacobian and accumulated noise), ``_measurements`` and ``_range_bearing`` evaluate
the range-bearing model, and :func:`graphslam_initialize` dead-reckons the poses and places each
landmark at its first sighting (Table 11.1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

import probmap.slam.landmark.graphslam._kernels as _k
from probmap._checks import is_finite_number, require_integer
from probmap._typing import FloatArray, IntArray
from probmap.geometry.se2 import wrap_angle
from probmap.models.measurement import RangeBearingModel
from probmap.models.motion import AckermannModel, VelocityModel

__all__ = [
    "GraphSLAMConfig",
    "GraphSLAMProblem",
    "graphslam_initialize",
    "motion_chain",
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
