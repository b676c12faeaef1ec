"""Sparse extended information filter (SEIF) SLAM, Probabilistic Robotics chapter 12.

The posterior over the robot pose and the landmarks is kept in information form, ``Omega`` and
``xi``, stored block-sparse (:mod:`probmap.slam.landmark._seif_store`). Each step touches only the robot
and a bounded set of *active* landmarks, so its cost does not grow with the map:

1. :meth:`SEIFSlam.motion_update` (Table 12.2): the Psi / lambda / Phi / kappa update, written for
   any motion model with ``G = d g / d x`` and ``Q = V M V^T``;
2. :meth:`SEIFSlam.measurement_update` (Table 12.3): add ``H^T R^-1 H`` and
   ``H^T R^-1 (z - z_hat + H mu)``;
3. :meth:`SEIFSlam.update_mean` (Table 12.5): amortised mean recovery over the robot and the
   active landmarks, plus a few coordinate-descent steps on passive landmarks per update; an
   exact sparse solve on demand (:meth:`SEIFSlam.recover_mean_exact`);
4. :meth:`SEIFSlam.sparsify` (Table 12.4): deactivate landmarks beyond ``max_active`` by
   conditioning on the passive landmarks at zero, marginalising, and the three-matrix form
   ``Omega~ = Omega1 - Omega2 + Omega3``, with ``xi~ = xi + (Omega~ - Omega) mu``.

Step order: the mean is updated after the measurement update and *before* sparsifying, because
sparsification keeps the mean fixed only at the mean it is given (notes/seif.md, "stale mean").

Two tiers, as in filterpy: pure functions on dense arrays (``*_information``, in
:mod:`probmap.slam.landmark.seif_steps`) that state each table's equations, and the stateful
:class:`SEIFSlam` that applies them to small dense systems gathered from the sparse store over
the robot and the active landmarks.

Deactivation policy (``max_active``, ``deactivation``): after each measurement update every
observed landmark is active; when more than ``max_active`` are, the ones whose link to the robot
carries the least information are deactivated (``"weakest"``, the default: smallest conditional
mutual information :func:`robot_link_information`, i.e. what Table 12.4 throws away when it cuts
the link), or the ones observed least recently (``"oldest"``; ties: the one observed earliest in
the batch goes first). On 20 simulated runs the weakest-link choice halved the median pose ANEES
at ``max_active = 10`` (10.1 -> 4.9) and cut the worst landmark RMSE from 3.0x to 2.2x the EKF's
(BENCHMARKS.md). ``max_active=None`` never sparsifies; then,
with exact mean recovery, the SEIF equals the EKF with batch measurement updates.

References: S. Thrun, Y. Liu, D. Koller, A. Ng, Z. Ghahramani, H. Durrant-Whyte, "Simultaneous
localization and mapping with sparse extended information filters", IJRR 23(7-8), 2004;
R. Eustice, M. Walter, J. Leonard, "Sparse extended information filters: insights into
sparsification", IROS 2005 (why sparsification is overconfident).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy import linalg as sla

from probmap._checks import require_integer
from probmap._typing import FloatArray, IntArray
from probmap.errors import SingularInformationError
from probmap.geometry.se2 import wrap_angle
from probmap.slam.landmark._seif_store import InformationStore
from probmap.slam.landmark.association import (
    NEW,
    associate_ml,
    chi2_gate,
    validate_initial_state,
    validate_observations,
)
from probmap.slam.landmark.seif_steps import (
    _cho_solve,
    measurement_update_information,
    motion_update_information,
    robot_link_information,
    sparsify_information,
)

__all__ = [
    "SEIFSlam",
    "SeifConfig",
    "SingularInformationError",
    "build_seif",
]


LANDMARK_COVARIANCE_EXACT_MAX = 5000
"""Up to this many landmarks, :meth:`SEIFSlam.landmarks` returns exact marginal covariances."""

CONTEXT_MAX = 128
"""At most this many context landmarks per sparsification (``SeifConfig.context_hops``)."""


# ---------------------------------------------------------------------------------------------
# Stateful tier
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SeifConfig:
    """Parameters of :class:`SEIFSlam` (see its docstring); loadable from a YAML mapping.

    Attributes
    ----------
    max_active : int or None
        Bound on the active set (None: unbounded, no sparsification).
    passive_sweeps : int
        Passive landmarks refreshed per update by one coordinate-descent step (round robin).
    exact_mean : bool
        Solve ``Omega mu = xi`` exactly (sparse LU) after every update: O(n), for tests.
    gate_probability : float
        Chi-square probability (2 dof) of the association gate.
    new_landmark_probability : float
        An unmatched observation whose every Mahalanobis distance exceeds this chi-square
        quantile starts a new landmark; between the two quantiles it is discarded.
    search_radius : float
        Association candidates are the landmarks whose mean lies within this distance (m) of an
        observation's inverse-model position (found through a spatial hash with cells this size).
    exact_covariance_max : int
        Up to this many landmarks, :attr:`SEIFSlam.pose_covariance` is the exact marginal
        (sparse LU, O(n) per call); beyond it, the covariance conditioned on the landmarks outside
        the robot's Markov blanket (smaller than the marginal).
    deactivation : {"weakest", "oldest"}
        Which landmarks leave the active set: those whose link to the robot carries the least
        information (:func:`robot_link_information`, default), or the least recently observed.
    context_hops : int
        0 (default): sparsify exactly as Table 12.4, conditioning on every passive landmark.
        ``k > 0`` (an extension, not in the book): the passive landmarks within ``k`` links of
        the active set (at most ``CONTEXT_MAX`` of them, nearest hops first) are marginalised
        with the deactivated ones instead (:func:`sparsify_information` with ``n_context``);
        still constant time per step. One hop removes most of the overconfidence
        (BENCHMARKS.md: median pose ANEES over 20 simulated runs at ``max_active = 10`` 4.9 ->
        2.7, the EKF's 2.5).
    """

    max_active: int | None = 10
    passive_sweeps: int = 4
    exact_mean: bool = False
    gate_probability: float = 0.99
    new_landmark_probability: float = 0.9999
    search_radius: float = 10.0
    exact_covariance_max: int = 150
    deactivation: str = "weakest"
    context_hops: int = 0

    def __post_init__(self) -> None:
        require_integer("context_hops", self.context_hops, 0)
        object.__setattr__(self, "context_hops", int(self.context_hops))
        if self.deactivation not in ("oldest", "weakest"):
            raise ValueError(
                f"deactivation must be 'oldest' or 'weakest', got {self.deactivation!r}"
            )
        if self.max_active is not None and self.max_active < 1:
            raise ValueError(f"max_active must be >= 1 or None, got {self.max_active}")
        if self.passive_sweeps < 0:
            raise ValueError(f"passive_sweeps must be >= 0, got {self.passive_sweeps}")
        if not 0 < self.gate_probability <= self.new_landmark_probability < 1:
            raise ValueError(
                "need 0 < gate_probability <= new_landmark_probability < 1, got "
                f"{self.gate_probability}, {self.new_landmark_probability}"
            )
        if not self.search_radius > 0:
            raise ValueError(f"search_radius must be > 0, got {self.search_radius}")


class SEIFSlam:
    """SEIF SLAM over a robot pose and 2-D point landmarks (Table 12.1).

    Parameters
    ----------
    motion_model
        Has ``predict(x, u, dt) -> (x_new, G, V)`` and ``control_covariance(u, dt) -> M``.
    measurement_model
        A :class:`~probmap.models.measurement.RangeBearingModel` (``predict_many``, ``inverse``,
        ``R``).
    initial_pose : array_like, shape (3,)
    initial_covariance : array_like, shape (3, 3)
        Symmetric positive definite.
    max_active, passive_sweeps, exact_mean, gate_probability, new_landmark_probability,
    search_radius, exact_covariance_max, deactivation, context_hops
        See :class:`SeifConfig`.
    """

    # every landmark estimator's first four arguments (EKFSLAM, GraphSLAM); then SeifConfig's
    # fields as keywords, a public signature.
    def __init__(
        self,
        motion_model: Any,
        measurement_model: Any,
        initial_pose: ArrayLike,
        initial_covariance: ArrayLike,
        *,
        max_active: int | None = 10,
        passive_sweeps: int = 4,
        exact_mean: bool = False,
        gate_probability: float = 0.99,
        new_landmark_probability: float = 0.9999,
        search_radius: float = 10.0,
        exact_covariance_max: int = 150,
        deactivation: str = "weakest",
        context_hops: int = 0,
    ) -> None:
        self.config = SeifConfig(
            max_active,
            passive_sweeps,
            exact_mean,
            gate_probability,
            new_landmark_probability,
            search_radius,
            exact_covariance_max,
            deactivation,
            context_hops,
        )
        mu0, P0 = validate_initial_state(initial_pose, initial_covariance)
        try:
            c = sla.cho_factor(P0)
        except np.linalg.LinAlgError as exc:
            raise ValueError("initial_covariance must be positive definite") from exc
        Omega0 = sla.cho_solve(c, np.eye(3))
        Omega0 = 0.5 * (Omega0 + Omega0.T)
        self.motion_model = motion_model
        self.measurement_model = measurement_model
        self._R = np.asarray(measurement_model.R, dtype=np.float64)
        self._store = InformationStore(Omega0, Omega0 @ mu0, mu0)
        self._slot_of: dict[int, int] = {}
        self._id_of: list[int] = []
        self._active: dict[int, int] = {}  # slot -> step it was last observed (insertion-ordered)
        self._step = 0
        self._next_id = 0
        self._sweep_at = 0
        self._cells: dict[tuple[int, int], set[int]] = {}
        self._cell_of: list[tuple[int, int]] = []
        self._version = 0
        self._cov_cache: tuple[int, FloatArray] | None = None
        self._gate = chi2_gate(gate_probability)
        self._new_gate = chi2_gate(new_landmark_probability)

    # ------------------------------------------------------------------ properties
    @property
    def store(self) -> InformationStore:
        """The block-sparse information store (read it; do not modify it)."""
        return self._store

    @property
    def n_landmarks(self) -> int:
        """Number of landmarks in the state."""
        return self._store.n

    @property
    def active_ids(self) -> IntArray:
        """External ids of the active landmarks, shape (a,)."""
        return np.array([self._id_of[s] for s in self._active], dtype=np.int64)

    @property
    def pose(self) -> FloatArray:
        """Current pose estimate ``(x, y, theta)`` (3,), theta wrapped."""
        p = self._store.robot_mu.copy()
        p[2] = float(wrap_angle(p[2]))
        return p

    @property
    def pose_covariance(self) -> FloatArray:
        """Covariance (3x3) of the pose: the marginal of ``Omega^-1``.

        Exact (sparse LU) up to ``exact_covariance_max`` landmarks; beyond it, the inverse of the
        information over the robot and the active landmarks (its Markov blanket), which
        conditions on the passive landmarks and so is smaller than the true marginal.
        """
        if self._cov_cache is not None and self._cov_cache[0] == self._version:
            return self._cov_cache[1].copy()
        st = self._store
        if st.n <= self.config.exact_covariance_max:
            from scipy.sparse.linalg import splu

            E = np.zeros((3 + 2 * st.n, 3))
            E[:3, :3] = np.eye(3)
            P = splu(st.to_sparse()).solve(E)[:3, :3]
        else:
            local = list(self._active)
            Omega, _, _ = st.gather(local)
            P = np.linalg.inv(Omega)[:3, :3]
        P = 0.5 * (P + P.T)
        self._cov_cache = (self._version, P)
        return P.copy()

    def information_matrix(self) -> FloatArray:
        """Dense ``Omega`` (3 + 2n, 3 + 2n), landmarks in slot order (small problems only)."""
        return np.asarray(self._store.to_sparse().toarray())

    def information_vector(self) -> FloatArray:
        """``xi`` (3 + 2n,), landmarks in slot order."""
        return self._store.xi_vector()

    def mean_vector(self) -> FloatArray:
        """The running mean estimate (3 + 2n,), robot theta unwrapped, landmarks in slot order."""
        return self._store.mu_vector()

    def slot_ids(self) -> IntArray:
        """External id of each landmark slot, shape (n,)."""
        return np.array(self._id_of, dtype=np.int64)

    def state_nbytes(self) -> int:
        """Bytes of numbers stored for the state (see ``InformationStore.state_nbytes``)."""
        return self._store.state_nbytes()

    def add_landmarks(self, ids: ArrayLike, xy: ArrayLike, cov: ArrayLike) -> None:
        """Add landmarks with independent Gaussian priors (a prior map), O(k).

        Parameters
        ----------
        ids : array_like, shape (k,)
            New landmark ids (>= 0, not yet in the state).
        xy : array_like, shape (k, 2)
            Prior means (world frame, m).
        cov : array_like, shape (k, 2, 2)
            Prior covariances, symmetric positive definite.
        """
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        cov = np.asarray(cov, dtype=np.float64).reshape(-1, 2, 2)
        if not (ids.shape[0] == xy.shape[0] == cov.shape[0]):
            raise ValueError("ids, xy and cov must have the same length")
        if np.any(ids < 0) or len(set(ids.tolist())) != ids.size:
            raise ValueError("landmark ids must be distinct and >= 0")
        if any(int(i) in self._slot_of for i in ids):
            raise ValueError("a landmark id is already in the state")
        if not (np.all(np.isfinite(xy)) and np.all(np.isfinite(cov))):
            raise ValueError("prior means and covariances must be finite")
        try:
            np.linalg.cholesky(cov)
        except np.linalg.LinAlgError as exc:
            raise ValueError("prior covariances must be positive definite") from exc
        info = np.linalg.inv(cov)
        st = self._store
        for i in range(ids.size):
            s = self._new_landmark(int(ids[i]), xy[i])
            st._omega[s] = info[i]
            st._xi[s] = info[i] @ xy[i]
        self._version += 1

    # ------------------------------------------------------------------ Table 12.2
    def predict(self, u: ArrayLike, dt: float) -> None:
        """Motion update with control ``u`` (2,) over ``dt`` seconds (Table 12.2)."""
        u = np.asarray(u, dtype=np.float64)
        if u.shape != (2,) or not np.all(np.isfinite(u)):
            raise ValueError(f"control u must be 2 finite numbers, got {u!r}")
        dt = float(dt)
        if not (math.isfinite(dt) and dt >= 0.0):
            raise ValueError(f"dt must be finite and >= 0, got {dt}")
        self.motion_update(u, dt)

    def motion_update(self, u: FloatArray, dt: float) -> None:
        """Table 12.2 on the robot and the active landmarks (the only ones linked to it)."""
        st = self._store
        mu_x = st.robot_mu
        x_new, G, V = self.motion_model.predict(mu_x, u, dt)
        M = self.motion_model.control_covariance(u, dt)
        Q = V @ M @ V.T
        delta = np.asarray(x_new, dtype=np.float64) - mu_x
        delta[2] = float(wrap_angle(delta[2]))
        slots = list(self._active)
        Omega, xi, mu = st.gather(slots)
        Omega_bar, xi_bar = motion_update_information(Omega, xi, mu, delta, G, Q)
        mu[:3] = mu_x + delta
        st.scatter(slots, Omega_bar, xi_bar, mu)
        self._version += 1

    # ------------------------------------------------------------------ Table 12.3 / 12.4 / 12.5
    def update(self, z: ArrayLike, ids: ArrayLike) -> None:
        """Measurement update, mean update and sparsification (Table 12.1, lines 3-5).

        Parameters
        ----------
        z : array_like, shape (k, 2)
            ``(range m, bearing rad)`` in the sensor frame.
        ids : array_like, shape (k,)
            Landmark ids; ``-1`` = unknown, associated by maximum likelihood with Mahalanobis
            gating on the locally recovered mean and covariance. Observations with a range
            <= 0 are ignored (as in the EKF).

        Raises
        ------
        SingularInformationError
            When an information block is singular or indefinite; the state is left unchanged.
        """
        z, ids = validate_observations(z, ids)
        positive = z[:, 0] > 1e-9  # a range <= 0 (noise near the sensor) has no bearing: drop it
        if not positive.all():
            z, ids = z[positive], ids[positive]
        self._step += 1
        if z.shape[0] and np.any(ids == -1):
            z, ids = self.associate(z, ids)
        n_before = self._store.n
        try:
            self._update_known(z, ids)
        except (np.linalg.LinAlgError, SingularInformationError) as exc:
            self._rollback(n_before)
            raise SingularInformationError(
                f"SEIF update at step {self._step} rejected: {exc}"
            ) from None
        self._version += 1
        if self.config.exact_mean:
            self.recover_mean_exact()
        else:
            self._sweep_passive(self.config.passive_sweeps)

    def _rollback(self, n_before: int) -> None:
        st = self._store
        for s in range(n_before, st.n):
            self._slot_of.pop(self._id_of[s], None)
            self._active.pop(s, None)
            cell = self._cell_of[s]
            self._cells.get(cell, set()).discard(s)
        del self._id_of[n_before:]
        del self._cell_of[n_before:]
        st.n = n_before
        del st.adjacency[n_before:]

    def _new_landmark(self, lid: int, xy: FloatArray) -> int:
        s = self._store.add_landmark(xy)
        self._slot_of[lid] = s
        self._id_of.append(lid)
        cell = self._cell(xy)
        self._cell_of.append(cell)
        self._cells.setdefault(cell, set()).add(s)
        self._next_id = max(self._next_id, lid + 1)
        return s

    def _cell(self, xy: FloatArray) -> tuple[int, int]:
        c = self.config.search_radius
        return (int(math.floor(xy[0] / c)), int(math.floor(xy[1] / c)))

    def _update_known(self, z: FloatArray, ids: IntArray) -> None:
        st = self._store
        old_obs: list[int] = []
        old_z: list[int] = []
        new_z: list[int] = []
        new_ids: list[int] = []
        for i in range(z.shape[0]):
            lid = int(ids[i])
            s = self._slot_of.get(lid)
            if s is not None:
                old_obs.append(s)
                old_z.append(i)
            elif lid not in new_ids:  # a new landmark seen twice in one batch: keep the first
                new_z.append(i)
                new_ids.append(lid)
        # the active set grows by the observed landmarks, most recently observed last
        for s in old_obs:
            self._active.pop(s, None)
            self._active[s] = self._step
        local = list(self._active)
        Omega, xi, mu = st.gather(local)
        pos = st.local_index(local)
        if old_obs:
            Omega, xi = self.measurement_update(Omega, xi, mu, z[old_z], [pos[s] for s in old_obs])
        mu = self.update_mean(local, Omega, xi, mu)
        if new_z:
            Omega, xi, mu = self._initialize_landmarks(local, Omega, xi, mu, z[new_z], new_ids)
            pos = st.local_index(local)
        Omega, xi, _ = self._deactivate_excess(local, Omega, xi, mu, pos)
        st.scatter(local, Omega, xi, mu)
        self._rebin(local)

    def _context(self, local: Sequence[int]) -> list[int]:
        """Passive landmarks within ``context_hops`` links of ``local`` (breadth first, capped)."""
        hops = self.config.context_hops
        if hops == 0:
            return []
        adjacency = self._store.adjacency
        seen = set(local)
        ring = list(local)
        out: list[int] = []
        for _ in range(hops):
            nxt: list[int] = []
            for s in ring:
                for t in adjacency[s]:
                    if t not in seen:
                        seen.add(t)
                        nxt.append(t)
                        if len(out) + len(nxt) >= CONTEXT_MAX:
                            return out + nxt
            if not nxt:
                break
            out.extend(nxt)
            ring = nxt
        return out

    def _sparsify_with_context(
        self,
        local: list[int],
        Omega: FloatArray,
        xi: FloatArray,
        mu: FloatArray,
        m0_rows: Sequence[int],
    ) -> tuple[FloatArray, FloatArray]:
        """Table 12.4 on the local system, with the context landmarks of ``context_hops``.

        ``Omega`` is the current local system over the robot and ``local`` (it may hold updates
        not yet scattered); the context's blocks come from the store, whose links between
        ``local`` and the context are unchanged by the motion and measurement updates.
        """
        ctx = self._context(local)
        if not ctx:
            return self.sparsify_local(Omega, xi, mu, m0_rows)
        d = Omega.shape[0]
        E, xi_e, mu_e = self._store.gather([*local, *ctx])
        E[:d, :d] = Omega
        xi_e[:d] = xi
        mu_e[:d] = mu
        E_t, xi_t = sparsify_information(E, xi_e, mu_e, m0_rows, n_context=len(ctx))
        return E_t[:d, :d], xi_t[:d]

    def _initialize_landmarks(
        self,
        local: list[int],
        Omega: FloatArray,
        xi: FloatArray,
        mu: FloatArray,
        z: FloatArray,
        new_ids: list[int],
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Add landmarks first seen now, from the inverse measurement model at the updated pose.

        Each starts with zero information, then receives its observation's Table 12.3 update
        (zero innovation at the initial point): the result equals the EKF's augmentation with
        ``P_mm = J_x P_xx J_x^T + J_z R J_z^T`` and ``P_m* = J_x P_x*``.
        """
        st = self._store
        k = len(new_ids)
        xy = np.stack([self.measurement_model.inverse(mu[:3], z[i])[0] for i in range(k)])
        d = Omega.shape[0]
        Omega = np.pad(Omega, ((0, 2 * k), (0, 2 * k)))
        xi = np.concatenate([xi, np.zeros(2 * k)])
        mu = np.concatenate([mu, xy.reshape(-1)])
        rows = [d + 2 * i for i in range(k)]
        for i, lid in enumerate(new_ids):
            s = self._new_landmark(lid, xy[i])
            local.append(s)
            self._active[s] = self._step
        Omega, xi = self.measurement_update(Omega, xi, mu, z, rows)
        del st  # slots were appended to the store by _new_landmark
        return Omega, xi, mu

    def sparsify_local(
        self, Omega: FloatArray, xi: FloatArray, mu: FloatArray, m0_rows: Sequence[int]
    ) -> tuple[FloatArray, FloatArray]:
        """Table 12.4 on a local dense system; see :func:`sparsify_information`."""
        return sparsify_information(Omega, xi, mu, m0_rows)

    def measurement_update(
        self,
        Omega: FloatArray,
        xi: FloatArray,
        mu: FloatArray,
        z: FloatArray,
        rows: Sequence[int],
    ) -> tuple[FloatArray, FloatArray]:
        """Table 12.3 on a local dense system (robot first, landmarks at ``rows``)."""
        lm = np.stack([mu[r : r + 2] for r in rows])
        z_hat, H_x, H_m = self.measurement_model.predict_many(mu[:3], lm)
        nu = z - z_hat
        nu[:, 1] = wrap_angle(nu[:, 1])
        return measurement_update_information(Omega, xi, mu, rows, H_x, H_m, nu, self._R)

    def update_mean(
        self, local: Sequence[int], Omega: FloatArray, xi: FloatArray, mu: FloatArray
    ) -> FloatArray:
        """Table 12.5 over the robot and the active landmarks, solved as one block.

        Block coordinate descent with the robot and ``local`` as a single block: the passive
        landmarks outside it enter at their current means,
        ``Omega_LL mu_L = xi_L - Omega_{L,rest} mu_rest``, solved by Cholesky (the fixed point of
        Table 12.5's sweeps over those variables). A failed Cholesky means the local information
        block is singular or indefinite.
        """
        b = xi.copy()
        if local:
            b[3:] -= self._store.boundary(local)
        return _cho_solve(Omega, b, "information block over the robot and active landmarks")

    def _deactivate_excess(
        self,
        local: list[int],
        Omega: FloatArray,
        xi: FloatArray,
        mu: FloatArray,
        pos: dict[int, int],
    ) -> tuple[FloatArray, FloatArray, bool]:
        """Table 12.4 on the local system for the slots beyond ``max_active``
        (:meth:`_deactivation`), which leave the active set: the new ``Omega``, ``xi`` and
        whether any did (:meth:`update` and :meth:`sparsify`)."""
        m0 = self._deactivation(local, Omega, pos)
        if m0:
            Omega, xi = self._sparsify_with_context(local, Omega, xi, mu, [pos[s] for s in m0])
            for s in m0:
                del self._active[s]
        return Omega, xi, bool(m0)

    def _deactivation(
        self, local: Sequence[int], Omega: FloatArray, pos: dict[int, int]
    ) -> list[int]:
        """Slots to deactivate (the deactivation policy); ``Omega`` is the local system."""
        limit = self.config.max_active
        if limit is None or len(self._active) <= limit:
            return []
        excess = len(self._active) - limit
        if self.config.deactivation == "weakest":
            slots = list(self._active)
            score = robot_link_information(Omega, [pos[s] for s in slots])
            order = np.argsort(score, kind="stable")
            return [slots[i] for i in order[:excess]]
        # dict order: least recently observed first (observed slots are re-inserted at the end)
        return list(self._active)[:excess]

    def sparsify(self) -> None:
        """Table 12.4 on the current state: deactivate beyond ``max_active`` (normally run by
        :meth:`update`)."""
        st = self._store
        local = list(self._active)
        Omega, xi, mu = st.gather(local)
        pos = st.local_index(local)
        Omega, xi, deactivated = self._deactivate_excess(local, Omega, xi, mu, pos)
        if not deactivated:
            return
        st.scatter(local, Omega, xi)
        self._version += 1

    def _rebin(self, slots: Sequence[int]) -> None:
        mus = self._store.mu_landmarks
        for s in slots:
            cell = self._cell(mus[s])
            old = self._cell_of[s]
            if cell != old:
                self._cells[old].discard(s)
                self._cells.setdefault(cell, set()).add(s)
                self._cell_of[s] = cell

    def _sweep_passive(self, count: int) -> None:
        """Table 12.5 on a few passive landmarks per update (round robin)."""
        st = self._store
        n = st.n
        if n == 0 or count == 0:
            return
        mu = st._mu
        done = 0
        tries = 0
        swept: list[int] = []
        while done < count and tries < n:
            s = self._sweep_at % n
            self._sweep_at += 1
            tries += 1
            if s in self._active:
                continue
            rhs = st._xi[s].copy()
            for t, block in st.adjacency[s].items():
                rhs -= (block if s < t else block.T) @ mu[t]
            mu[s] = np.linalg.solve(st._omega[s], rhs)
            swept.append(s)
            done += 1
        self._rebin(swept)

    def recover_mean_exact(self) -> FloatArray:
        """Solve ``Omega mu = xi`` exactly (sparse LU), store and return ``mu`` (3 + 2n,)."""
        from scipy.sparse.linalg import splu

        st = self._store
        mu = splu(st.to_sparse()).solve(st.xi_vector())
        st.set_mu_vector(mu)
        self._rebin(range(st.n))
        return np.asarray(mu)

    # ------------------------------------------------------------------ data association
    def associate(self, z: FloatArray, ids: IntArray) -> tuple[FloatArray, IntArray]:
        """Maximum-likelihood association of the observations with ``ids == -1``.

        Candidates are the landmarks whose mean lies within ``search_radius`` of an
        observation's inverse-model position (spatial hash, O(1) in the map size). Their joint
        covariance with the robot is recovered locally: the inverse of the information over the
        robot, the active landmarks and the candidates (conditioned on the rest at their means). Each observation goes to the
        candidate of smallest Mahalanobis distance inside the ``gate_probability`` gate (each
        candidate at most once per batch, greedy by distance); one beyond the
        ``new_landmark_probability`` gate of every candidate starts a new landmark; the rest are
        dropped.

        Returns
        -------
        z, ids : the kept observations and their ids (new ids for new landmarks).
        """
        st = self._store
        unknown = np.flatnonzero(ids == -1)
        out_ids = ids.copy()
        keep = np.ones(len(ids), dtype=bool)
        mu_x = st.robot_mu
        guess = np.stack([self.measurement_model.inverse(mu_x, z[i])[0] for i in unknown])
        cand = self._candidates(guess, self.config.search_radius)
        if cand:
            local = list(self._active)
            seen = set(local)
            for s in cand:
                if s not in seen:
                    seen.add(s)
                    local.append(s)
            Omega, _, _ = st.gather(local)
            what = "data association: local information block"
            Sigma = _cho_solve(Omega, np.eye(Omega.shape[0]), what)
            pos = st.local_index(local)
            rows = np.array([pos[s] for s in cand])
            lm = st.mu_landmarks[cand]
            z_hat, H_x, H_m = self.measurement_model.predict_many(mu_x, lm)
            c = len(cand)
            idx = np.concatenate(
                [np.broadcast_to(np.arange(3), (c, 3)), rows[:, None] + np.arange(2)], axis=1
            )
            S_blocks = Sigma[idx[:, :, None], idx[:, None, :]]  # (c, 5, 5)
            H = np.concatenate([H_x, H_m], axis=2)  # (c, 2, 5)
            S = H @ S_blocks @ H.transpose(0, 2, 1) + self._R
            S = 0.5 * (S + S.transpose(0, 2, 1))
            match = associate_ml(
                z[unknown], z_hat, S, gate=self._gate, new_gate=self._new_gate
            ).match
        else:
            match = np.full(len(unknown), NEW, dtype=np.int64)
        taken = {int(i) for i in ids[ids >= 0]}
        for o, i in enumerate(unknown):
            m = int(match[o])
            if m >= 0 and self._id_of[cand[m]] not in taken:
                out_ids[i] = self._id_of[cand[m]]
                taken.add(int(out_ids[i]))
            elif m == NEW:
                out_ids[i] = self._next_id
                self._next_id += 1
            else:
                keep[i] = False
        return z[keep], out_ids[keep]

    def _candidates(self, points: FloatArray, radius: float) -> list[int]:
        """Landmarks whose mean lies within ``radius`` of any of ``points`` (m, 2)."""
        found: set[int] = set()
        for p in points:
            i0, j0 = self._cell(p)
            for i in (i0 - 1, i0, i0 + 1):
                for j in (j0 - 1, j0, j0 + 1):
                    cell = self._cells.get((i, j))
                    if cell:
                        found.update(cell)
        if not found:
            return []
        arr = np.array(sorted(found))
        d = self._store.mu_landmarks[arr][:, None, :] - points[None, :, :]
        near = np.any(np.einsum("cpi,cpi->cp", d, d) <= radius * radius, axis=1)
        return [int(s) for s in arr[near]]

    # ------------------------------------------------------------------ outputs
    def landmarks(self) -> tuple[IntArray, FloatArray, FloatArray]:
        """Mapped landmarks after an exact mean recovery.

        Returns
        -------
        ids : ndarray, shape (n,), int64
        xy : ndarray, shape (n, 2)
            Means (world frame, m).
        cov : ndarray, shape (n, 2, 2)
            Marginal covariances: exact (sparse LU) up to ``LANDMARK_COVARIANCE_EXACT_MAX`` (5000),
            otherwise the conditional ``Omega_jj^-1`` (smaller than the marginal), with a
            ``RuntimeWarning``.
        """
        st = self._store
        n = st.n
        mu = self.recover_mean_exact()
        ids = np.array(self._id_of, dtype=np.int64)
        xy = mu[3:].reshape(n, 2).copy()
        if n == 0:
            return ids, xy, np.zeros((0, 2, 2))
        if n <= LANDMARK_COVARIANCE_EXACT_MAX:
            from scipy.sparse.linalg import splu

            lu = splu(st.to_sparse())
            cov: FloatArray = np.empty((n, 2, 2))
            chunk = 256
            for a in range(0, n, chunk):
                b = min(n, a + chunk)
                E = np.zeros((3 + 2 * n, 2 * (b - a)))
                E[3 + 2 * a + np.arange(2 * (b - a)), np.arange(2 * (b - a))] = 1.0
                X = lu.solve(E)
                for j in range(a, b):
                    r = 3 + 2 * j
                    cj = 2 * (j - a)
                    cov[j] = X[r : r + 2, cj : cj + 2]
        else:
            warnings.warn(
                f"{n} landmarks > {LANDMARK_COVARIANCE_EXACT_MAX}: "
                "landmark covariances are conditional (Omega_jj^-1), smaller than the marginals",
                RuntimeWarning,
                stacklevel=2,
            )
            cov = np.asarray(np.linalg.inv(st.omega_diag), dtype=np.float64)
        cov = np.asarray(0.5 * (cov + cov.transpose(0, 2, 1)), dtype=np.float64)
        return ids, xy, cov


def build_seif(dataset: Any, config: SeifConfig | None = None) -> SEIFSlam:
    """Construct a :class:`SEIFSlam` for a landmark dataset (its models and initial pose)."""
    cfg = config if config is not None else SeifConfig()
    return SEIFSlam(
        dataset.motion_model,
        dataset.measurement_model,
        dataset.initial_pose,
        dataset.initial_covariance,
        max_active=cfg.max_active,
        passive_sweeps=cfg.passive_sweeps,
        exact_mean=cfg.exact_mean,
        gate_probability=cfg.gate_probability,
        new_landmark_probability=cfg.new_landmark_probability,
        search_radius=cfg.search_radius,
        exact_covariance_max=cfg.exact_covariance_max,
        deactivation=cfg.deactivation,
        context_hops=cfg.context_hops,
    )
