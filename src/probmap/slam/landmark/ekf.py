"""EKF SLAM with known (Table 10.1) and unknown (Table 10.2, section 10.3.3) correspondences.

State ``mu = (x, y, theta, m_1x, m_1y, ..., m_nx, m_ny)`` and dense covariance ``P``
(``3 + 2n`` square), world frame, metres and radians.

Costs: the prediction touches only the robot rows and columns (``P_rr`` and ``P_rm``), O(n); the
measurement update of a scan of ``k`` observations is one batched update with the sparse 2x5
Jacobian blocks: ``P H^T`` is gathered from ``P[:, robot]`` and ``P[:, landmark]`` columns in
O(n k), and the covariance is corrected by a single rank-4k product, O(n^2 k), written in place
through BLAS. The full ``(3 + 2n)`` square Jacobians of the textbook presentation (``F_x``,
``F_{x,j}``) are never built.

The covariance correction is the Joseph form ``(I - K H) P (I - K H)^T + K R K^T``, expanded with
``S = H P H^T + R`` into ``P - K (P H^T)^T - (P H^T) K^T + K S K^T``: it is symmetric by
construction and stays positive semi-definite even when ``K`` is not exactly optimal (rounding).

Two tiers, as in :mod:`probmap.slam.landmark.seif`: pure functions on the state arrays that state the
book's equations (:func:`ekf_slam_predict`, Table 10.1 lines 2-5; :func:`ekf_slam_correct`, lines
12-18 batched; :func:`ekf_slam_augment`, landmark initialisation; :func:`ekf_slam_innovation_covariances`
and :func:`landmark_covariances`), and the stateful :class:`EKFSLAM`, which owns the
landmark bookkeeping (ids, slots, provisional landmarks, association) and calls them. The models
it is built with are typed by the protocols :class:`EKFMotionModel` and
:class:`EKFMeasurementModel` (:class:`~probmap.models.motion.VelocityModel`,
:class:`~probmap.models.motion.AckermannModel` and
:class:`~probmap.models.measurement.RangeBearingModel` fit).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import blas, cho_factor, cho_solve

from probmap._typing import FloatArray, IntArray
from probmap.geometry.se2 import wrap_angle
from probmap.slam.landmark.association import (
    NEW,
    associate_ml,
    chi2_gate,
    innovation,
    validate_initial_state,
    validate_observations,
)

__all__ = [
    "EKFConfig",
    "EKFMeasurementModel",
    "EKFMotionModel",
    "EKFSLAM",
    "build_ekf",
    "ekf_slam_augment",
    "ekf_slam_correct",
    "ekf_slam_innovation_covariances",
    "ekf_slam_predict",
    "landmark_covariances",
]


class EKFMotionModel(Protocol):
    """What :class:`EKFSLAM` needs of a motion model (e.g. :class:`~probmap.models.motion.VelocityModel`)."""

    def predict(
        self, x: ArrayLike, u: ArrayLike, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``g(u, x)`` (3,), ``G = dg/dx`` (3, 3) and ``V = dg/du`` (3, m) for a step of ``dt`` s."""
        ...

    def control_covariance(self, u: ArrayLike, dt: float) -> FloatArray:
        """Covariance ``M`` (m, m) of the control noise for a step of ``dt`` s."""
        ...


class EKFMeasurementModel(Protocol):
    """What :class:`EKFSLAM` needs of a landmark sensor (e.g.
    :class:`~probmap.models.measurement.RangeBearingModel`)."""

    @property
    def R(self) -> FloatArray:
        """Measurement noise covariance (2, 2), (m^2, rad^2)."""
        ...

    def predict_many(
        self, pose: ArrayLike, landmarks: ArrayLike
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``z_hat (n, 2)``, ``H_x (n, 2, 3)``, ``H_m (n, 2, 2)`` of ``landmarks (n, 2)``."""
        ...

    def inverse(self, pose: ArrayLike, z: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Landmark ``(2,)`` from ``z (2,)`` and its Jacobians ``J_x (2, 3)``, ``J_z (2, 2)``."""
        ...


# ---------------------------------------------------------------------------------------------
# Function tier: Table 10.1 on the state arrays (robot = rows 0..2, landmark j = rows 3+2j, 4+2j)
# ---------------------------------------------------------------------------------------------
def ekf_slam_predict(
    mu: FloatArray, P: FloatArray, x_new: FloatArray, G: FloatArray, Q: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """EKF SLAM prediction (Probabilistic Robotics Table 10.1, lines 2-5), in place, O(n).

    With ``F_x`` the (3, 3 + 2n) robot selector, the book's ``mu_bar = mu + F_x^T delta`` and
    ``Sigma_bar = G_full Sigma G_full^T + F_x^T R_t F_x`` with ``G_full = I + F_x^T (G - I) F_x``
    touch only the robot rows and columns:

    - ``mu_x <- x_new``;
    - ``P_rr <- G P_rr G^T + Q``;
    - ``P_rm <- G P_rm`` and ``P_mr <- P_rm^T``; ``P_mm`` is unchanged.

    Parameters
    ----------
    mu : ndarray, shape (3 + 2n,)
        State mean ``(x, y, theta, m_1x, m_1y, ...)``, world frame (m, rad); modified in place.
    P : ndarray, shape (3 + 2n, 3 + 2n)
        State covariance; modified in place.
    x_new : ndarray, shape (3,)
        Predicted pose ``g(u, mu_x)`` (heading wrapped), world frame.
    G : ndarray, shape (3, 3)
        Pose Jacobian ``d g / d x`` at ``mu_x``.
    Q : ndarray, shape (3, 3)
        Motion noise in pose space, ``V M V^T`` (the book's ``R_t``), may be singular.

    Returns
    -------
    mu, P : ndarray
        The same arrays, updated.
    """
    mu[:3] = x_new
    P[:3, :3] = G @ P[:3, :3] @ G.T + Q
    if P.shape[0] > 3:
        P_rm = G @ P[:3, 3:]
        P[:3, 3:] = P_rm
        P[3:, :3] = P_rm.T
    return mu, P


def landmark_covariances(P: FloatArray, slots: IntArray) -> FloatArray:
    """Marginal 2x2 covariances ``P_mm`` of the landmarks in ``slots``.

    Parameters
    ----------
    P : ndarray, shape (3 + 2n, 3 + 2n)
        State covariance.
    slots : ndarray of int, shape (k,)
        Landmark slots (0-based; slot ``j`` is rows ``3 + 2j`` and ``4 + 2j``).

    Returns
    -------
    ndarray, shape (k, 2, 2)
        (m^2).
    """
    r = 3 + 2 * np.asarray(slots, dtype=np.int64)
    out = np.empty((r.size, 2, 2))
    out[:, 0, 0] = P[r, r]
    out[:, 0, 1] = P[r, r + 1]
    out[:, 1, 0] = P[r + 1, r]
    out[:, 1, 1] = P[r + 1, r + 1]
    return out


def ekf_slam_innovation_covariances(
    P: FloatArray, slots: IntArray, H_x: FloatArray, H_m: FloatArray, R: FloatArray
) -> FloatArray:
    """Per-landmark innovation covariances ``S_j = H_j P H_j^T + R`` (Table 10.1 line 15,
    Table 10.2 line 16), from the sparse 2x5 blocks ``H_j = [H_x, H_m]``.

    Parameters
    ----------
    P : ndarray, shape (3 + 2n, 3 + 2n)
        State covariance.
    slots : ndarray of int, shape (k,)
        Landmark slots.
    H_x : ndarray, shape (k, 2, 3)
        ``d z / d pose`` of each landmark's predicted measurement.
    H_m : ndarray, shape (k, 2, 2)
        ``d z / d landmark``.
    R : ndarray, shape (2, 2)
        Measurement noise covariance ((m, rad) for range-bearing).

    Returns
    -------
    ndarray, shape (k, 2, 2)
    """
    sl = np.asarray(slots, dtype=np.int64)
    cols = (3 + 2 * sl[:, None] + np.arange(2)).ravel()
    P_rm = P[:3, cols].reshape(3, sl.size, 2).transpose(1, 0, 2)  # (k, 3, 2)
    P_mm = landmark_covariances(P, sl)
    HxPrm = H_x @ P_rm  # (k, 2, 2)
    S: FloatArray = (
        H_x @ P[:3, :3] @ H_x.transpose(0, 2, 1)
        + HxPrm @ H_m.transpose(0, 2, 1)
        + H_m @ HxPrm.transpose(0, 2, 1)
        + H_m @ P_mm @ H_m.transpose(0, 2, 1)
        + R
    )
    return S


def ekf_slam_correct(
    mu: FloatArray,
    P: FloatArray,
    z: FloatArray,
    slots: IntArray,
    z_hat: FloatArray,
    H_x: FloatArray,
    H_m: FloatArray,
    R: FloatArray,
) -> tuple[FloatArray, FloatArray, float]:
    """Batched EKF SLAM correction (Table 10.1, lines 12-18) for ``k`` matched observations.

    The book fuses one observation at a time; here all ``k`` are fused at once with the stacked
    ``H`` (2k, 3 + 2n) whose rows are ``[H_x | 0 | H_m | 0]``, never built:

    - ``P H^T`` (N, 2k) is gathered from the robot and the observed landmarks' columns, O(n k);
    - ``S = H P H^T + R_blockdiag`` (2k, 2k), ``K = P H^T S^-1`` (Cholesky);
    - ``mu <- mu + K nu`` with ``nu = z - z_hat`` (bearing wrapped), heading wrapped;
    - ``P <- (I - K H) P (I - K H)^T + K R K^T`` (Joseph form), expanded into one rank-4k BLAS
      update ``P - W U^T`` with ``C = P H^T - K S / 2``, ``U = [K, C]``, ``W = [C, K]``.

    Parameters
    ----------
    mu : ndarray, shape (N,), N = 3 + 2n
        State mean, world frame (m, rad); updated in place.
    P : ndarray, shape (N, N), C-contiguous
        State covariance; updated in place where BLAS allows (use the returned array).
    z : ndarray, shape (k, 2)
        Measurements ``(range m, bearing rad)`` in the sensor frame.
    slots : ndarray of int, shape (k,)
        Landmark slot of each measurement (distinct).
    z_hat, H_x, H_m : ndarray, shapes (k, 2), (k, 2, 3), (k, 2, 2)
        Predicted measurements and Jacobians at ``mu`` (``predict_many`` of the sensor model).
    R : ndarray, shape (2, 2)
        Measurement noise covariance.

    Returns
    -------
    mu : ndarray, shape (N,)
    P : ndarray, shape (N, N)
    nis : float
        Normalised innovation squared ``nu^T S^-1 nu`` (chi-square with 2k dof when consistent).

    Raises
    ------
    ValueError
        If ``S`` is not positive definite.
    """
    k = z.shape[0]
    N = P.shape[0]
    cols = (3 + 2 * slots[:, None] + np.arange(2)).ravel()  # (2k,) landmark columns
    # P H^T from the robot columns and each observation's landmark columns: (N, 2k)
    PHt = P[:, :3] @ H_x.reshape(2 * k, 3).T
    P_lm = P[:, cols].reshape(N, k, 2)
    PHt += np.einsum("nkj,kij->nki", P_lm, H_m).reshape(N, 2 * k)
    # S = H P H^T + R, gathered from the rows of P H^T that H touches: (2k, 2k)
    S = H_x.reshape(2 * k, 3) @ PHt[:3]
    S += np.einsum("kij,kjm->kim", H_m, PHt[cols].reshape(k, 2, 2 * k)).reshape(2 * k, 2 * k)
    for i in range(k):
        S[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] += R
    S = 0.5 * (S + S.T)
    nu = innovation(z, z_hat).ravel()
    try:
        cS = cho_factor(S)
    except np.linalg.LinAlgError as exc:
        raise ValueError("innovation covariance is not positive definite") from exc
    K = cho_solve(cS, PHt.T).T  # (N, 2k) = P H^T S^-1
    nis = float(nu @ cho_solve(cS, nu))
    mu += K @ nu
    mu[2] = wrap_angle(mu[2])
    # Joseph form expanded: P -= K C^T + C K^T with C = P H^T - K S / 2
    C = PHt - 0.5 * (K @ S)
    U = np.hstack([K, C])
    W = np.hstack([C, K])
    Pt = P.T  # Fortran-ordered view of the C-ordered P: BLAS writes in place
    out = blas.dgemm(alpha=-1.0, a=W, b=U, trans_b=True, beta=1.0, c=Pt, overwrite_c=True)
    if not np.shares_memory(out, P):
        P = np.ascontiguousarray(out.T)
    return mu, P, nis


def ekf_slam_augment(
    mu: FloatArray,
    P: FloatArray,
    xy: FloatArray,
    J_x: FloatArray,
    J_z: FloatArray,
    R: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Append ``k`` new landmarks initialised from the inverse measurement model.

    Instead of the book's infinite prior (Table 10.1 lines 9-11), each new landmark
    ``m = h^-1(x, z)`` gets its full cross-covariance: ``P_m* = J_x P_r*`` (with the old state),
    ``P_mm' = J_x P_rr J_x'^T`` between new landmarks (correlated through the pose) plus
    ``J_z R J_z^T`` on each diagonal block.

    Parameters
    ----------
    mu : ndarray, shape (N,)
        State mean.
    P : ndarray, shape (N, N)
        State covariance.
    xy : ndarray, shape (k, 2)
        New landmark positions, world frame (m).
    J_x : ndarray, shape (k, 2, 3)
        ``d m / d pose`` of each.
    J_z : ndarray, shape (k, 2, 2)
        ``d m / d z`` of each.
    R : ndarray, shape (2, 2)
        Measurement noise covariance.

    Returns
    -------
    mu : ndarray, shape (N + 2k,)
    P : ndarray, shape (N + 2k, N + 2k)
        New arrays; the new landmarks take slots ``n .. n + k - 1`` in order.
    """
    k = xy.shape[0]
    N = P.shape[0]
    Jx_all = J_x.reshape(2 * k, 3)
    cross = Jx_all @ P[:3, :]  # (2k, N): new landmarks vs old state
    new_block = Jx_all @ P[:3, :3] @ Jx_all.T  # correlated through the pose
    for i in range(k):
        new_block[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] += J_z[i] @ R @ J_z[i].T
    P_new = np.empty((N + 2 * k, N + 2 * k))
    P_new[:N, :N] = P
    P_new[N:, :N] = cross
    P_new[:N, N:] = cross.T
    P_new[N:, N:] = 0.5 * (new_block + new_block.T)
    return np.concatenate([mu, xy.ravel()]), P_new


@dataclass(frozen=True)
class EKFConfig:
    """Settings of :class:`EKFSLAM`.

    Parameters
    ----------
    gate_probability : float
        Chi-square probability of the association gate (2 dof), unknown correspondences.
    new_landmark_probability : float
        An observation whose nearest landmark lies beyond this chi-square quantile starts a new
        (provisional) landmark; between the two gates it is discarded as ambiguous.
    accept_hits : int
        Observations needed before a provisional landmark is reported (section 10.3.3).
    max_misses : int
        A provisional landmark predicted visible but not seen this many times is removed.
    visibility_range : float
        Range (m) within which a landmark is expected to be seen (for miss counting).
    visibility_fov : float
        Field of view (rad) centred on the sensor heading, for miss counting.
    min_range : float
        Observations closer than this (m) are ignored.
    outlier_probability : float or None
        With known correspondences, observations whose Mahalanobis distance exceeds this
        chi-square quantile are rejected as outliers (counted in ``rejected_outliers``);
        None fuses everything.
    symmetrize_every : int
        Re-symmetrize ``P`` after this many updates (guards against rounding drift).
    """

    gate_probability: float = 0.99
    new_landmark_probability: float = 0.9999
    accept_hits: int = 3
    max_misses: int = 5
    visibility_range: float = np.inf
    visibility_fov: float = 2 * np.pi
    min_range: float = 0.0
    outlier_probability: float | None = None
    symmetrize_every: int = 50

    def __post_init__(self) -> None:
        if not 0 < self.gate_probability <= self.new_landmark_probability < 1:
            raise ValueError("need 0 < gate_probability <= new_landmark_probability < 1")
        if self.accept_hits < 1 or self.max_misses < 0 or self.symmetrize_every < 1:
            raise ValueError("accept_hits >= 1, max_misses >= 0, symmetrize_every >= 1 required")
        if not self.min_range >= 0 or not self.visibility_range > 0 or not self.visibility_fov > 0:
            raise ValueError(
                "min_range must be >= 0 and visibility_range, visibility_fov > 0 (not NaN), got "
                f"{self.min_range}, {self.visibility_range}, {self.visibility_fov}"
            )
        if self.outlier_probability is not None and not 0 < self.outlier_probability < 1:
            raise ValueError(
                f"outlier_probability must lie in (0, 1), got {self.outlier_probability}"
            )


class EKFSLAM:
    """Extended Kalman filter SLAM (Probabilistic Robotics, chapter 10).

    Parameters
    ----------
    motion_model : EKFMotionModel
        ``predict(x, u, dt) -> (x', G, V)`` and ``control_covariance(u, dt)``, e.g.
        :class:`~probmap.models.motion.VelocityModel`.
    measurement_model : EKFMeasurementModel
        ``R``, ``predict_many`` and ``inverse``, e.g.
        :class:`~probmap.models.measurement.RangeBearingModel`.
    initial_pose : array_like, shape (3,)
        Start pose ``(x, y, theta)``, world frame (m, rad).
    initial_covariance : array_like, shape (3, 3)
        Its covariance.
    config : EKFConfig, optional

    Notes
    -----
    ``update(z, ids)`` uses the given ids (known correspondences, Table 10.1) for ``ids >= 0`` and
    maximum-likelihood association (Table 10.2) for ``ids == -1``. New landmarks are initialised
    from the inverse measurement model with their full cross-covariance (not with the book's
    infinite prior), ``P_mm = J_x P_rr J_x^T + J_z R J_z^T`` and ``P_m* = J_x P_r*``.

    The arithmetic is that of the function tier (:func:`ekf_slam_predict`,
    :func:`ekf_slam_correct`, :func:`ekf_slam_augment`); this class keeps the state, the landmark
    ids and the association logic.
    """

    # every landmark estimator's first four arguments (SEIFSlam, GraphSLAM): one way to build them.
    def __init__(
        self,
        motion_model: EKFMotionModel,
        measurement_model: EKFMeasurementModel,
        initial_pose: ArrayLike,
        initial_covariance: ArrayLike,
        config: EKFConfig | None = None,
    ) -> None:
        mu, P0 = validate_initial_state(initial_pose, initial_covariance)
        # positive semi-definite: a zero covariance (a pose known exactly) is allowed, unlike
        # SEIFSlam, which needs the inverse
        lowest = float(np.linalg.eigvalsh(P0).min())
        if lowest < -1e-12 * max(1.0, float(np.abs(P0).max())):
            raise ValueError(
                f"initial_covariance must be positive semi-definite (smallest eigenvalue {lowest:g})"
            )
        self.motion_model = motion_model
        self.measurement_model = measurement_model
        self.config = config if config is not None else EKFConfig()
        self._mu = mu
        self._P = np.array(P0, order="C")
        self._R = np.asarray(measurement_model.R, dtype=np.float64)
        self._ids = np.zeros(0, dtype=np.int64)  # landmark id per slot
        self._hits = np.zeros(0, dtype=np.int64)
        self._misses = np.zeros(0, dtype=np.int64)
        self._confirmed = np.zeros(0, dtype=bool)
        self._slot: dict[int, int] = {}
        self._next_id = 0
        self._gate = chi2_gate(self.config.gate_probability)
        self._new_gate = chi2_gate(self.config.new_landmark_probability)
        self._outlier_gate = (
            None
            if self.config.outlier_probability is None
            else chi2_gate(self.config.outlier_probability)
        )
        self.rejected_outliers = 0
        """Known-id observations rejected by the outlier gate so far."""
        self._n_updates = 0
        self.last_nis: float = np.nan
        """Normalised innovation squared of the last update (``nu^T S^-1 nu``)."""
        self.last_nis_dof: int = 0
        """Degrees of freedom of :attr:`last_nis` (2 per matched observation)."""

    # ------------------------------------------------------------------ state access
    @property
    def n_landmarks(self) -> int:
        """Number of landmarks in the state (provisional ones included)."""
        return int(self._ids.size)

    @property
    def mean(self) -> FloatArray:
        """Full state mean (3 + 2n,) (a copy)."""
        return self._mu.copy()

    @property
    def covariance(self) -> FloatArray:
        """Full covariance (3 + 2n, 3 + 2n) (a copy)."""
        return self._P.copy()

    @property
    def pose(self) -> FloatArray:
        """Pose estimate (3,)."""
        return self._mu[:3].copy()

    @property
    def pose_covariance(self) -> FloatArray:
        """Pose covariance (3, 3)."""
        return self._P[:3, :3].copy()

    def landmarks(self) -> tuple[IntArray, FloatArray, FloatArray]:
        """Confirmed landmarks: ``ids (n,)``, ``xy (n, 2)``, ``cov (n, 2, 2)``."""
        sel = np.flatnonzero(self._confirmed)
        xy = self._mu[3:].reshape(-1, 2)[sel]
        cov = self._landmark_blocks(sel)
        return self._ids[sel].copy(), xy.copy(), cov

    def _landmark_blocks(self, slots: IntArray) -> FloatArray:
        return landmark_covariances(self._P, slots)

    # ------------------------------------------------------------------ prediction
    def predict(self, u: ArrayLike, dt: float) -> None:
        """EKF prediction (Table 10.1, lines 2-5): only ``P_rr`` and ``P_rm`` change, O(n).

        ``u`` is the control of :attr:`motion_model` (``(v, w)`` m/s, rad/s for the velocity
        model) held for ``dt`` s; see :func:`ekf_slam_predict`.
        """
        if dt == 0.0:
            return
        u = np.asarray(u, dtype=np.float64)
        x_new, G, V = self.motion_model.predict(self._mu[:3], u, dt)
        M = self.motion_model.control_covariance(u, dt)
        ekf_slam_predict(self._mu, self._P, x_new, G, V @ M @ V.T)

    # ------------------------------------------------------------------ measurement update
    def update(self, z: ArrayLike, ids: ArrayLike) -> None:
        """Measurement update with ``z`` (k, 2) range/bearing and ``ids`` (k,), -1 = unknown.

        Observations with known ids are matched directly (Table 10.1); unknown ones by maximum
        likelihood with gating (Table 10.2). New landmarks are added first, then all matched
        observations are fused in one batched Joseph-form update.
        """
        z, ids = validate_observations(z, ids)
        if z.shape[0] == 0:  # no scan: nothing to do
            self.last_nis, self.last_nis_dof = np.nan, 0
            return
        keep = z[:, 0] > max(self.config.min_range, 1e-9)
        z, ids = z[keep], ids[keep]
        self.last_nis, self.last_nis_dof = np.nan, 0
        n_before = self.n_landmarks
        slots = np.full(z.shape[0], -1, dtype=np.int64)
        new_rows: list[int] = []
        new_ids: list[int] = []
        known = ids >= 0
        for i in np.flatnonzero(known):
            s = self._slot.get(int(ids[i]))
            if s is None:
                if int(ids[i]) in new_ids:  # seen twice in one scan: drop the second
                    continue
                new_rows.append(int(i))
                new_ids.append(int(ids[i]))
            else:
                slots[i] = s
        if self._outlier_gate is not None and np.any(slots >= 0):
            self._reject_outliers(z, slots)
        unknown = np.flatnonzero(~known)
        if unknown.size:
            match = self._associate(z[unknown])
            for i, m in zip(unknown, match, strict=True):
                if m >= 0:
                    slots[i] = m
                elif m == NEW:
                    new_rows.append(int(i))
                    new_ids.append(-1)
        if z.shape[0] and n_before and not self._confirmed.all():
            # a step without observations is "no scan", not evidence against landmarks
            self._count_misses(slots, n_before)
        matched = np.flatnonzero(slots >= 0)
        if matched.size:
            self._hits[slots[matched]] += 1
            self._confirmed |= self._hits >= self.config.accept_hits
            self._fuse(z[matched], slots[matched])
        if new_rows:
            self._add_landmarks(z[new_rows], new_ids)
        self._remove_spurious()

    def _reject_outliers(self, z: FloatArray, slots: IntArray) -> None:
        """Drop known-id observations outside the outlier gate (marks them unmatched)."""
        sel = np.flatnonzero(slots >= 0)
        z_hat, _, _, S = self._predicted_observations(slots[sel])
        nu = innovation(z[sel], z_hat)
        d2 = np.einsum("ki,ki->k", nu, np.linalg.solve(S, nu[..., None])[..., 0])
        bad = sel[d2 > self._outlier_gate]
        slots[bad] = -2
        self.rejected_outliers += int(bad.size)

    def _predicted_observations(
        self, slots: IntArray | None = None
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """``z_hat``, ``H_x (n, 2, 3)``, ``H_m (n, 2, 2)``, ``S (n, 2, 2)`` of ``slots`` (all)."""
        sl = np.arange(self.n_landmarks) if slots is None else np.asarray(slots, dtype=np.int64)
        lm = self._mu[3:].reshape(-1, 2)[sl]
        z_hat, H_x, H_m = self.measurement_model.predict_many(self._mu[:3], lm)
        S = ekf_slam_innovation_covariances(self._P, sl, H_x, H_m, self._R)
        return z_hat, H_x, H_m, S

    def _associate(self, z: FloatArray) -> IntArray:
        """Maximum-likelihood data association (Table 10.2, lines 16-18)."""
        if self.n_landmarks == 0:
            return np.full(z.shape[0], NEW, dtype=np.int64)
        z_hat, _, _, S = self._predicted_observations()
        return associate_ml(z, z_hat, S, gate=self._gate, new_gate=self._new_gate).match

    def _count_misses(self, slots: IntArray, n_before: int) -> None:
        """Count landmarks predicted visible but not observed (section 10.3.3)."""
        if n_before == 0:
            return
        lm = self._mu[3 : 3 + 2 * n_before].reshape(-1, 2)
        z_hat, _, _ = self.measurement_model.predict_many(self._mu[:3], lm)
        visible = (z_hat[:, 0] <= self.config.visibility_range) & (
            np.abs(z_hat[:, 1]) <= self.config.visibility_fov / 2
        )
        seen = np.zeros(n_before, dtype=bool)
        seen[slots[slots >= 0]] = True
        self._misses[:n_before] += visible & ~seen

    def _remove_spurious(self) -> None:
        bad = (~self._confirmed) & (self._misses > self.config.max_misses)
        if not bad.any():
            return
        keep_slots = np.flatnonzero(~bad)
        rows = np.concatenate([np.arange(3), (3 + 2 * keep_slots[:, None] + np.arange(2)).ravel()])
        self._mu = self._mu[rows]
        self._P = np.ascontiguousarray(self._P[np.ix_(rows, rows)])
        self._ids = self._ids[keep_slots]
        self._hits = self._hits[keep_slots]
        self._misses = self._misses[keep_slots]
        self._confirmed = self._confirmed[keep_slots]
        self._slot = {int(i): s for s, i in enumerate(self._ids)}

    def _add_landmarks(self, z: FloatArray, ids: list[int]) -> None:
        """Augment the state with new landmarks from the inverse measurement model."""
        k = z.shape[0]
        sensor = self.measurement_model
        xy = np.empty((k, 2))
        Jx = np.empty((k, 2, 3))
        Jz = np.empty((k, 2, 2))
        for i in range(k):
            xy[i], Jx[i], Jz[i] = sensor.inverse(self._mu[:3], z[i])
        self._mu, self._P = ekf_slam_augment(self._mu, self._P, xy, Jx, Jz, self._R)
        assigned: list[int] = []
        for i in ids:
            if i < 0:
                while self._next_id in self._slot:
                    self._next_id += 1
                i = self._next_id
                self._next_id += 1
            self._slot[i] = self._ids.size + len(assigned)
            assigned.append(i)
        known = np.array([i >= 0 for i in ids])
        self._ids = np.concatenate([self._ids, np.asarray(assigned, dtype=np.int64)])
        self._hits = np.concatenate([self._hits, np.ones(k, dtype=np.int64)])
        self._misses = np.concatenate([self._misses, np.zeros(k, dtype=np.int64)])
        confirmed = known | (1 >= self.config.accept_hits)
        self._confirmed = np.concatenate([self._confirmed, confirmed])

    def _fuse(self, z: FloatArray, slots: IntArray) -> None:
        """Batched EKF correction (Table 10.1, lines 12-18) for ``k`` matched observations."""
        lm = self._mu[3:].reshape(-1, 2)[slots]
        z_hat, H_x, H_m = self.measurement_model.predict_many(self._mu[:3], lm)
        self._mu, self._P, self.last_nis = ekf_slam_correct(
            self._mu, self._P, z, slots, z_hat, H_x, H_m, self._R
        )
        self.last_nis_dof = 2 * z.shape[0]
        self._n_updates += 1
        if self._n_updates % self.config.symmetrize_every == 0:
            self._P = np.ascontiguousarray(0.5 * (self._P + self._P.T))


def build_ekf(dataset: Any, config: EKFConfig | None = None) -> EKFSLAM:
    """An :class:`EKFSLAM` for a landmark dataset (its models, initial pose and covariance), as
    :func:`~probmap.slam.landmark.graphslam.build_graphslam` and :func:`~probmap.slam.landmark.seif.build_seif`
    build theirs.

    Parameters
    ----------
    dataset : landmark dataset
        Anything with ``motion_model``, ``measurement_model``, ``initial_pose`` (3,) and
        ``initial_covariance`` (3, 3) (a simulated world, UTIAS MRCLAM, Victoria Park).
    config : EKFConfig, optional
        The filter's settings (default: ``EKFConfig()``).

    Returns
    -------
    EKFSLAM
    """
    return EKFSLAM(
        dataset.motion_model,
        dataset.measurement_model,
        dataset.initial_pose,
        dataset.initial_covariance,
        config,
    )
