"""The GraphSLAM estimator: :class:`GraphSLAM` records the steps of a log like an online
estimator (``predict``, ``update``) and solves the whole log in :meth:`GraphSLAM.smooth`;
:func:`build_graphslam` builds one on a landmark dataset's models.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from probmap._checks import is_finite_number
from probmap._typing import FloatArray, IntArray
from probmap.slam.landmark.association import (
    validate_control,
    validate_initial_state,
    validate_observations,
)
from probmap.slam.landmark.graphslam.correspondence import optimize_graphslam_front_end
from probmap.slam.landmark.graphslam.optimize import GraphSLAMResult, optimize_graphslam
from probmap.slam.landmark.graphslam.problem import (
    GraphSLAMConfig,
    GraphSLAMProblem,
    segment_log,
)

__all__ = [
    "GraphSLAM",
    "build_graphslam",
]


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
