"""GraphSLAM for point landmarks (Probabilistic Robotics, chapter 11), known correspondences.

The full-SLAM posterior over the whole path and the map is the minimum of

.. math:: J = (x_0 - \\mu_0)^T \\Omega_0 (x_0 - \\mu_0)
          + \\sum_t (x_t - g(u_t, x_{t-1}))^T R_t^{-1} (x_t - g(u_t, x_{t-1}))
          + \\sum_{t,i} \\rho\\big((z_t^i - h(x_t, m_{c_t^i}))^T Q^{-1} (z_t^i - h(\\cdot))\\big)

(eq. 11.4-11.5 with the anchoring prior of Table 11.2 line 2 and an optional robust ``rho``).
The motion model ``g`` and its noise are those of the EKF (``predict`` and
``control_covariance`` of :mod:`probmap.models.motion`: ``R_t = V M V^T``), and the measurement
model ``h`` with ``Q`` is :class:`~probmap.models.measurement.RangeBearingModel`.

How the book's tables map onto this package:

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

The parts, each importing only the ones before it (the names below are all re-exported here):

* :mod:`~probmap.slam.landmark.graphslam.problem`: :class:`GraphSLAMConfig`,
  :class:`GraphSLAMProblem` and :func:`segment_log`, the motion chain (:func:`motion_chain`),
  the measurement model and the initialization (Table 11.1, :func:`graphslam_initialize`).
* :mod:`~probmap.slam.landmark.graphslam.linearize`: Table 11.2 (:func:`graphslam_linearize`,
  :class:`LinearizedSystem`, the robust weights and the chi-square gate).
* :mod:`~probmap.slam.landmark.graphslam.solve`: Tables 11.3-11.4 (:func:`graphslam_reduce`,
  :func:`graphslam_solve_reduced`, the sparse and banded Cholesky factorizations,
  :func:`graphslam_solve_schur`) and :func:`marginal_covariances`.
* :mod:`~probmap.slam.landmark.graphslam.optimize`: Table 11.5 (:func:`optimize_graphslam`,
  :class:`GraphSLAMResult`, the incremental start and the recovery of the intermediate steps).
* :mod:`~probmap.slam.landmark.graphslam.correspondence`: Tables 11.8-11.9 and the front end
  for unknown correspondences (:func:`graphslam_correspondence_test`,
  :func:`optimize_graphslam_unknown`, :func:`graphslam_associate`,
  :func:`optimize_graphslam_front_end`).
* :mod:`~probmap.slam.landmark.graphslam.estimator`: the class :class:`GraphSLAM` and
  :func:`build_graphslam`.
* ``_kernels``: the numba kernels (odometry chain, step smoother, front end, sparse Cholesky).
"""

from __future__ import annotations

from probmap.slam.landmark.graphslam.correspondence import (
    graphslam_associate,
    graphslam_correspondence_test,
    landmark_joint_covariance,
    landmark_pair_covariances,
    optimize_graphslam_front_end,
    optimize_graphslam_unknown,
)
from probmap.slam.landmark.graphslam.estimator import GraphSLAM, build_graphslam
from probmap.slam.landmark.graphslam.linearize import LinearizedSystem, graphslam_linearize
from probmap.slam.landmark.graphslam.optimize import GraphSLAMResult, optimize_graphslam
from probmap.slam.landmark.graphslam.problem import (
    GraphSLAMConfig,
    GraphSLAMProblem,
    graphslam_initialize,
    motion_chain,
    segment_log,
)
from probmap.slam.landmark.graphslam.solve import (
    graphslam_reduce,
    graphslam_solve_reduced,
    graphslam_solve_schur,
    marginal_covariances,
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
    "motion_chain",
    "optimize_graphslam",
    "segment_log",
]
