"""FastSLAM 1.0 and 2.0 with known and unknown correspondences (Probabilistic Robotics ch. 13,
Tables 13.1-13.3): a particle filter over robot paths, each particle carrying one small EKF per
landmark (Rao-Blackwellization: given the path, landmarks are independent).

Per step, for every particle ``m``:

1. **Motion.** FastSLAM 1.0 samples the pose from the motion model. The model's motion is a
   rigid displacement ``Delta(u, dt)`` in the robot frame, so the sample is the particle's pose
   composed with ``Delta`` of a noisy control; the control noise ``N(0, M(u, dt))`` enters
   through the displacement's Jacobian ``V`` (``Delta(u + e) ~ Delta(u) + V e``), the same
   linearization the EKF uses for its ``Q = V M V'`` (Table 10.1 line 4).
2. **Proposal (2.0 only, Table 13.3 lines 6-14).** The pose is drawn from the Gaussian that
   also accounts for the measurements of landmarks the particle has seen: starting from the
   predicted pose and ``R_t = V M V'``, each such measurement updates the pose Gaussian as an
   EKF would (``Sigma_x = (H_x' Q^-1 H_x + Sigma_x^-1)^-1``, ``Q = R + H_m Sigma_m H_m'``);
   the sample is drawn from the result.
3. **Landmarks (Table 13.1 lines 8-20).** A landmark seen for the first time is initialized
   from the inverse measurement model (mean and ``J_z R J_z'``); a known one gets the EKF
   update ``K = Sigma H_m' Q^-1``.
4. **Weights.** 1.0: the product of ``N(z; z_hat, Q)`` over the step's known landmarks (line
   18); 2.0: of ``N(z; z_hat, H_x R_t H_x' + Q)`` (line 16), the measurement's likelihood
   under the proposal's prior. Low-variance resampling (Table 4.4) runs when the effective
   sample size drops below ``resample_threshold * M``.

The estimate reported each step is the weighted mean pose (circular mean for the heading) and
its weighted covariance; the map is the landmarks of the heaviest particle.

**Unknown correspondences (Table 13.2).** Each particle associates each observation with the
landmark of largest likelihood (under the proposal's prior with 2.0) that no earlier
observation of the step took, or starts a new landmark when that likelihood is below ``p0``
(``new_landmark_likelihood``, also the new landmark's importance factor). Each landmark keeps
the book's counter: +1 when observed, -1 when inside the perceptual range and not observed,
removed below 0; :meth:`FastSLAM.landmarks` reports those whose counter reached ``min_count``
(the provisional list).

**Landmark storage (section 13.8).** :class:`LandmarkTree` keeps the particles' landmark
filters in Montemerlo's balanced binary tree shared between particles: resampling copies
roots, an update copies the ``O(log N)`` shared nodes of one path. :class:`FlatLandmarks`
keeps ``(M, N)`` arrays (``O(M N)`` per resample) and gives the same estimates; the tree is the
default. The per-step arithmetic (proposal, draws, landmark updates, weights) and the
association run in numba kernels (:mod:`probmap.slam.landmark._fastslam_kernels`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from probmap._typing import BoolArray, FloatArray, IntArray
from probmap.filters.resampling import effective_sample_size, low_variance_resample
from probmap.geometry.se2 import compose, wrap_angle
from probmap.slam.landmark.association import validate_control, validate_observations

__all__ = ["FastSLAM", "FastSLAMConfig", "FlatLandmarks", "LandmarkTree"]


@dataclass(frozen=True)
class FastSLAMConfig:
    """Parameters of :class:`FastSLAM`.

    Parameters
    ----------
    n_particles : int
        Particles (paths).
    version : {1, 2}
        FastSLAM 1.0 (motion-model proposal) or 2.0 (measurement-aware proposal).
    resample_threshold : float
        Resample when the effective sample size falls below this share of the particles
        (1.0: every step).
    seed : int
        Seed of the random generator.
    landmark_store : {"tree", "flat"}
        Where the particles keep their landmark filters: ``"tree"``, the book's shared
        balanced tree (:class:`LandmarkTree`: resampling copies ``O(1)`` per particle, an
        update ``O(log N)`` nodes), or ``"flat"``, one ``(M, N)`` array per quantity
        (:class:`FlatLandmarks`: resampling copies ``O(M N)``). Both give the same estimates.
    new_landmark_likelihood : float
        Unknown correspondences: ``p0`` of Table 13.2 line 15, the likelihood (a density in
        the measurement's units, 1 / (m rad)) above which an observation is explained by a
        known landmark rather than a new one; also the importance factor of a new landmark.
    min_count : int
        Unknown correspondences: a landmark is reported by :meth:`FastSLAM.landmarks` once its
        counter (Table 13.2's ``i``: +1 when observed, -1 when in view and not observed) has
        reached this value (the book's provisional list; the counter below 0 removes it).
    visibility_range : float
        Range (m) within which a landmark is expected to be observed (the perceptual range of
        Table 13.2 line 29).
    visibility_fov : float
        Field of view (rad) centred on the sensor heading, for the same test.
    """

    n_particles: int = 100
    version: int = 2
    resample_threshold: float = 0.5
    seed: int = 0
    landmark_store: str = "tree"
    new_landmark_likelihood: float = 1e-3
    min_count: int = 2
    visibility_range: float = math.inf
    visibility_fov: float = 2.0 * math.pi

    def __post_init__(self) -> None:
        if self.n_particles < 1:
            raise ValueError(f"n_particles must be >= 1, got {self.n_particles}")
        if self.version not in (1, 2):
            raise ValueError(f"version must be 1 or 2, got {self.version}")
        if not 0.0 <= self.resample_threshold <= 1.0:
            raise ValueError(
                f"resample_threshold must lie in [0, 1], got {self.resample_threshold}"
            )
        if self.landmark_store not in ("tree", "flat"):
            raise ValueError(
                f"landmark_store must be 'tree' or 'flat', got {self.landmark_store!r}"
            )
        if not (math.isfinite(self.new_landmark_likelihood) and self.new_landmark_likelihood > 0):
            raise ValueError(
                f"new_landmark_likelihood must be a finite number > 0, got "
                f"{self.new_landmark_likelihood}"
            )
        if self.min_count < 1:
            raise ValueError(f"min_count must be >= 1, got {self.min_count}")
        if not (self.visibility_range > 0 and self.visibility_fov > 0):
            raise ValueError(
                f"visibility_range and visibility_fov must be > 0, got {self.visibility_range}, "
                f"{self.visibility_fov}"
            )


class FlatLandmarks:
    """Every particle's landmark filters as dense arrays: column ``c`` of particle ``m`` at
    ``mean[m, c] (2,)``, ``cov[m, c] (2, 2)``, ``count[m, c]``, present where ``found[m, c]``.
    Resampling copies all ``M N`` entries; kept as the plain reference of :class:`LandmarkTree`.

    Parameters
    ----------
    n_particles : int
    """

    def __init__(self, n_particles: int) -> None:
        m = n_particles
        self.mean = np.zeros((m, 0, 2))
        self.cov = np.zeros((m, 0, 2, 2))
        self.count = np.zeros((m, 0), dtype=np.int64)
        self.found = np.zeros((m, 0), dtype=bool)

    @property
    def n_cols(self) -> int:
        """Columns (landmark slots) the store can hold."""
        return int(self.found.shape[1])

    def ensure_cols(self, n: int) -> None:
        """Make room for columns ``0 .. n - 1``."""
        extra = n - self.n_cols
        if extra <= 0:
            return
        m = self.found.shape[0]
        self.mean = np.concatenate([self.mean, np.zeros((m, extra, 2))], 1)
        self.cov = np.concatenate([self.cov, np.zeros((m, extra, 2, 2))], 1)
        self.count = np.concatenate([self.count, np.zeros((m, extra), dtype=np.int64)], 1)
        self.found = np.concatenate([self.found, np.zeros((m, extra), dtype=bool)], 1)

    def gather(self, cols: IntArray) -> tuple[FloatArray, FloatArray, IntArray, BoolArray]:
        """Column ``cols[m]`` of each particle ``m`` (``-1``: none): ``mean (M, 2)``, ``cov
        (M, 2, 2)``, ``count (M,)`` and ``found (M,)`` (the values of rows not found are
        unspecified)."""
        m = len(cols)
        ok = cols >= 0
        rows = np.flatnonzero(ok)
        mean, cov = np.zeros((m, 2)), np.zeros((m, 2, 2))
        count, found = np.zeros(m, dtype=np.int64), np.zeros(m, dtype=bool)
        c = cols[ok]
        mean[ok], cov[ok] = self.mean[rows, c], self.cov[rows, c]
        count[ok], found[ok] = self.count[rows, c], self.found[rows, c]
        return mean, cov, count, found

    def scatter(self, cols: IntArray, mean: FloatArray, cov: FloatArray, count: IntArray) -> None:
        """Write row ``m`` as column ``cols[m]`` of particle ``m`` (``-1``: untouched)."""
        ok = cols >= 0
        rows, c = np.flatnonzero(ok), cols[ok]
        self.mean[rows, c], self.cov[rows, c] = mean[ok], cov[ok]
        self.count[rows, c], self.found[rows, c] = count[ok], True

    def clear(self, cols: IntArray) -> None:
        """Remove column ``cols[m]`` of particle ``m`` (``-1``: untouched)."""
        ok = cols >= 0
        self.found[np.flatnonzero(ok), cols[ok]] = False

    def resample(self, keep: IntArray) -> None:
        """Particle ``m`` becomes a copy of particle ``keep[m]``."""
        self.mean, self.cov = self.mean[keep], self.cov[keep]
        self.count, self.found = self.count[keep], self.found[keep]

    def dense(
        self, particles: IntArray | None = None
    ) -> tuple[FloatArray, FloatArray, IntArray, BoolArray]:
        """All columns of ``particles`` (default all): ``(P, N, 2)``, ``(P, N, 2, 2)``,
        ``(P, N)``, ``(P, N)``."""
        sel = slice(None) if particles is None else particles
        return self.mean[sel], self.cov[sel], self.count[sel], self.found[sel]

    def nbytes(self) -> int:
        """Bytes held (``O(M N)``)."""
        return int(self.mean.nbytes + self.cov.nbytes + self.count.nbytes + self.found.nbytes)


class LandmarkTree:
    """Every particle's landmark filters in one pool of tree nodes shared between particles
    (Probabilistic Robotics section 13.8; Montemerlo et al. 2002).

    Column ``c`` of a particle is the leaf reached from the particle's root by the bits of
    ``c``, most significant first, in a balanced binary tree of depth ``D = ceil(log2 N)``.
    Particles share subtrees: :meth:`resample` copies roots and reference counts, no landmark;
    :meth:`scatter` and :meth:`clear` copy only the shared nodes on a landmark's path (``D +
    1`` at most) and rewrite exclusive ones in place (copy-on-write). The interface is that of
    :class:`FlatLandmarks`, and so are the values read back.

    Parameters
    ----------
    n_particles : int
    capacity : int
        Initial size of the node pool (it doubles when full).

    Attributes
    ----------
    depth : int
        ``D``; the tree holds ``2**D`` columns.
    nodes_copied : int
        Nodes allocated by path copying so far (the tree's share of an update's cost).
    """

    def __init__(self, n_particles: int, capacity: int = 1024) -> None:
        from probmap.slam.landmark import _fastslam_kernels as k

        self._k = k
        cap = max(int(capacity), 2)
        self._child = np.zeros((cap, 2), dtype=np.int64)
        self._refc = np.zeros(cap, dtype=np.int64)
        self._mean = np.zeros((cap, 2))
        self._cov = np.zeros((cap, 2, 2))
        self._count = np.zeros(cap, dtype=np.int64)
        self._free = np.zeros(cap, dtype=np.int64)
        self._free[: cap - 1] = np.arange(cap - 1, 0, -1)  # node 0 is the empty subtree
        self._top = np.array([cap - 1], dtype=np.int64)
        self._copied = np.zeros(1, dtype=np.int64)
        self.roots = np.zeros(n_particles, dtype=np.int64)
        self.depth = 0
        self._n_cols = 0

    @property
    def nodes_copied(self) -> int:
        return int(self._copied[0])

    @property
    def nodes_in_use(self) -> int:
        """Nodes held by some particle (the empty node 0 not counted)."""
        return int(len(self._refc) - 1 - self._top[0])

    @property
    def n_cols(self) -> int:
        return self._n_cols

    def _reserve(self, n: int) -> None:
        """At least ``n`` free nodes (the pool grows by doubling)."""
        if self._top[0] >= n:
            return
        cap = len(self._refc)
        grow = max(cap, n)
        new_cap = cap + grow
        self._child = np.concatenate([self._child, np.zeros((grow, 2), dtype=np.int64)])
        self._refc = np.concatenate([self._refc, np.zeros(grow, dtype=np.int64)])
        self._mean = np.concatenate([self._mean, np.zeros((grow, 2))])
        self._cov = np.concatenate([self._cov, np.zeros((grow, 2, 2))])
        self._count = np.concatenate([self._count, np.zeros(grow, dtype=np.int64)])
        free = np.zeros(new_cap, dtype=np.int64)
        top = int(self._top[0])
        free[:top] = self._free[:top]
        free[top : top + grow] = np.arange(new_cap - 1, cap - 1, -1)
        self._free = free
        self._top[0] = top + grow

    def ensure_cols(self, n: int) -> None:
        """Make room for columns ``0 .. n - 1`` (the tree grows a level at a time)."""
        self._n_cols = max(self._n_cols, n)
        while (1 << self.depth) < n:
            self._reserve(len(self.roots))
            self._k.tree_grow(self._child, self._refc, self._free, self._top, self.roots)
            self.depth += 1

    def gather(self, cols: IntArray) -> tuple[FloatArray, FloatArray, IntArray, BoolArray]:
        """As :meth:`FlatLandmarks.gather`."""
        m = len(self.roots)
        mean, cov = np.zeros((m, 2)), np.zeros((m, 2, 2))
        count, found = np.zeros(m, dtype=np.int64), np.zeros(m, dtype=bool)
        self._k.tree_gather(self._child, self._mean, self._cov, self._count, self.roots,
                            np.ascontiguousarray(cols, dtype=np.int64), self.depth, mean, cov,
                            count, found)  # fmt: skip
        return mean, cov, count, found

    def scatter(self, cols: IntArray, mean: FloatArray, cov: FloatArray, count: IntArray) -> None:
        """As :meth:`FlatLandmarks.scatter`."""
        self._reserve(len(self.roots) * (self.depth + 1))
        self._k.tree_scatter(self._child, self._refc, self._mean, self._cov, self._count,
                             self._free, self._top, self.roots,
                             np.ascontiguousarray(cols, dtype=np.int64), self.depth,
                             np.ascontiguousarray(mean, dtype=np.float64),
                             np.ascontiguousarray(cov, dtype=np.float64),
                             np.ascontiguousarray(count, dtype=np.int64),
                             self._copied)  # fmt: skip

    def clear(self, cols: IntArray) -> None:
        """As :meth:`FlatLandmarks.clear`."""
        self._reserve(len(self.roots) * (self.depth + 1))
        self._k.tree_clear(self._child, self._refc, self._mean, self._cov, self._count,
                           self._free, self._top, self.roots,
                           np.ascontiguousarray(cols, dtype=np.int64), self.depth,
                           self._copied)  # fmt: skip

    def resample(self, keep: IntArray) -> None:
        """Particle ``m`` takes the root of particle ``keep[m]``: ``O(M)``, no node copied."""
        old = self.roots
        new = np.ascontiguousarray(old[keep])
        self._k.tree_incref(self._refc, new)
        self._k.tree_release(self._child, self._refc, self._free, self._top, old)
        self.roots = new

    def dense(
        self, particles: IntArray | None = None
    ) -> tuple[FloatArray, FloatArray, IntArray, BoolArray]:
        """As :meth:`FlatLandmarks.dense` (one walk over each particle's tree)."""
        roots = self.roots if particles is None else np.ascontiguousarray(self.roots[particles])
        p, n = len(roots), self._n_cols
        mean, cov = np.zeros((p, n, 2)), np.zeros((p, n, 2, 2))
        count, found = np.zeros((p, n), dtype=np.int64), np.zeros((p, n), dtype=bool)
        self._k.tree_dense(self._child, self._mean, self._cov, self._count, roots, self.depth,
                           mean, cov, count, found)  # fmt: skip
        return mean, cov, count, found

    def nbytes(self) -> int:
        """Bytes of the nodes in use (``O(M log N + N)`` after resampling, not ``O(M N)``) and
        of the roots."""
        per_node = 2 * 8 + 8 + 2 * 8 + 4 * 8 + 8 + 8  # child, refc, mean, cov, count, free
        return int(self.nodes_in_use * per_node + self.roots.nbytes)


class FastSLAM:
    """FastSLAM 1.0 / 2.0 with known or unknown correspondences (a :class:`LandmarkSLAM
    <probmap.slam.landmark.base.LandmarkSLAM>`: ``predict`` then ``update`` each step).

    Parameters
    ----------
    motion_model : VelocityModel or AckermannModel
        ``predict(x, u, dt) -> (x_new, G, V)`` and ``control_covariance(u, dt)``.
    measurement_model : RangeBearingModel
        ``R`` and the sensor offset.
    initial_pose : array_like, shape (3,)
        Every particle starts here (the map frame is the first pose's, as for the EKF).
    config : FastSLAMConfig, optional

    Notes
    -----
    ``update(z, ids)`` takes either landmark ids (``>= 0``, known correspondences) or ``-1``
    for every observation (unknown correspondences, Table 13.2); one filter takes one kind.

    Examples
    --------
    >>> import numpy as np
    >>> from probmap.models.motion import VelocityModel
    >>> from probmap.models.measurement import RangeBearingModel
    >>> slam = FastSLAM(VelocityModel(), RangeBearingModel(), [0.0, 0.0, 0.0],
    ...                 FastSLAMConfig(n_particles=20))
    >>> slam.predict([1.0, 0.0], 0.1)
    >>> slam.update([[2.0, 0.0]], [7])
    >>> ids, xy, cov = slam.landmarks()
    >>> ids.tolist(), xy.shape
    ([7], (1, 2))
    """

    def __init__(
        self,
        motion_model: Any,
        measurement_model: Any,
        initial_pose: ArrayLike,
        config: FastSLAMConfig | None = None,
    ) -> None:
        self.config = cfg = config or FastSLAMConfig()
        x0 = np.asarray(initial_pose, dtype=np.float64)
        if x0.shape != (3,) or not np.all(np.isfinite(x0)):
            raise ValueError(f"initial_pose must be 3 finite numbers, got {initial_pose!r}")
        self.motion_model = motion_model
        self.measurement_model = measurement_model
        self._R = np.asarray(measurement_model.R, dtype=np.float64)
        self._rng = np.random.default_rng(cfg.seed)
        m = cfg.n_particles
        self.particles = np.repeat(x0[None, :], m, axis=0)
        self.log_weights = np.zeros(m)
        self.store: FlatLandmarks | LandmarkTree = (
            LandmarkTree(m) if cfg.landmark_store == "tree" else FlatLandmarks(m)
        )
        self._known: bool | None = None  # set by the first update with observations
        self._slot: dict[int, int] = {}  # known ids: landmark id -> column
        self._next_col = np.zeros(m, dtype=np.int64)  # unknown ids: each particle's next column
        self._log_p0 = math.log(cfg.new_landmark_likelihood)
        self._Rt = np.zeros((3, 3))  # motion noise of the last prediction (2.0's proposal)
        self._predicted = self.particles.copy()
        self.resamples = 0

    # ------------------------------------------------------------------ steps
    def predict(self, u: ArrayLike, dt: float) -> None:
        """Motion: every particle moves by the displacement of a noisy control."""
        u = validate_control(u)
        if not (math.isfinite(dt) and dt >= 0):
            raise ValueError(f"dt must be a finite number >= 0, got {dt}")
        if dt == 0:
            self._Rt = np.zeros((3, 3))
            self._predicted = self.particles.copy()
            return
        delta, _, V = self.motion_model.predict(np.zeros(3), u, dt)
        M = self.motion_model.control_covariance(u, dt)
        self._Rt = V @ M @ V.T
        mean = compose(self.particles, np.asarray(delta))
        self._predicted = mean
        if self.config.version == 2:
            # the pose is drawn in update(), from the proposal (Table 13.3)
            self.particles = mean.copy()
            return
        L = np.linalg.cholesky(M + 1e-18 * np.eye(2))
        e = self._rng.standard_normal((len(mean), 2)) @ L.T
        noisy = delta[None, :] + e @ V.T  # Delta(u + e) to first order, in the robot frame
        self.particles = compose(self.particles, noisy)
        self.particles[:, 2] = wrap_angle(self.particles[:, 2])

    def update(self, z: ArrayLike, ids: ArrayLike) -> None:
        """Measurements ``z (k, 2)`` (range m, bearing rad) of landmarks ``ids (k,)``: all
        ``>= 0`` (known correspondences) or all ``-1`` (unknown, Table 13.2)."""
        zs, idx = validate_observations(z, ids)
        if idx.size:
            known = bool(idx[0] >= 0)
            if np.any((idx >= 0) != known) or (self._known is not None and known != self._known):
                raise ValueError(
                    "FastSLAM takes either known ids (>= 0) or unknown ones (-1), not both"
                )
            self._known = known
        m = len(self.particles)
        if not idx.size or self._known:
            for j in idx:
                if int(j) not in self._slot:
                    self._slot[int(j)] = len(self._slot)
            self.store.ensure_cols(len(self._slot))
            cols = np.asarray([self._slot[int(j)] for j in idx], dtype=np.int64)
            colmat = np.repeat(cols[:, None], m, axis=1)
            new_lm = None
        else:
            colmat, new_lm, unseen = self._associate(zs)
        logw = self._measurement_step(zs, colmat, new_lm is not None)
        if new_lm is not None:
            self._count_misses(unseen)
        self.log_weights += logw
        self.log_weights -= self.log_weights.max()
        w = np.exp(self.log_weights)
        w /= w.sum()
        if effective_sample_size(w) < self.config.resample_threshold * len(w):
            keep = low_variance_resample(w, self._rng)
            self.particles = self.particles[keep]
            self.store.resample(keep)
            self._next_col = self._next_col[keep]
            self.log_weights = np.zeros(len(keep))
            self.resamples += 1

    def add_landmarks(self, ids: ArrayLike, xy: ArrayLike, cov: ArrayLike) -> None:
        """A prior map with known ids, before the first update: every particle holds landmark
        ``ids[i]`` at ``xy[i] (2,)`` (m) with covariance ``cov[i] (2, 2)`` (m^2). The tree
        store keeps one copy shared by all particles.

        Parameters
        ----------
        ids : array_like, shape (n,), int, >= 0
        xy : array_like, shape (n, 2)
        cov : array_like, shape (n, 2, 2)
        """
        idx = np.asarray(ids, dtype=np.int64).reshape(-1)
        pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        covs = np.asarray(cov, dtype=np.float64).reshape(-1, 2, 2)
        if not (len(idx) == len(pts) == len(covs)):
            raise ValueError(f"ids, xy and cov have {len(idx)}, {len(pts)} and {len(covs)} rows")
        if np.any(idx < 0) or len(set(idx.tolist())) != len(idx):
            raise ValueError("prior landmark ids must be distinct and >= 0")
        if not (np.all(np.isfinite(pts)) and np.all(np.isfinite(covs))):
            raise ValueError("prior landmarks must be finite")
        if self._known is not None or self._slot:
            raise ValueError("add_landmarks takes a prior map before the first update")
        self._known = True
        m = len(self.particles)
        self.store.ensure_cols(len(idx))
        only_first = np.full(m, -1, dtype=np.int64)
        for c, j in enumerate(idx.tolist()):
            self._slot[j] = c
            only_first[0] = c
            self.store.scatter(
                only_first,
                np.repeat(pts[c : c + 1], m, 0),
                np.repeat(covs[c : c + 1], m, 0),
                np.ones(m, dtype=np.int64),
            )
        self.store.resample(np.zeros(m, dtype=np.int64))  # every particle takes the first's

    def _associate(self, zs: FloatArray) -> tuple[IntArray, BoolArray, BoolArray]:
        """Maximum-likelihood association per particle (Table 13.2 lines 5-15): each
        observation goes to the landmark of largest likelihood not yet taken this step, or to
        a new landmark (the particle's next column) when none exceeds ``p0``.

        Returns ``cols (k, M)``, ``new (k, M)`` and ``unseen (M, N)``: landmarks in the
        perceptual range that no observation matched (their counters go down).
        """
        k, m = len(zs), len(self.particles)
        mean, cov, _, found = self.store.dense()
        n = found.shape[1]
        cols = np.full((k, m), -1, dtype=np.int64)
        new = np.zeros((k, m), dtype=bool)
        unseen = np.zeros((m, n), dtype=bool)
        v2 = self.config.version == 2 and bool(self._Rt.any())
        poses = self._predicted if v2 else self.particles
        if n:
            from probmap.slam.landmark._fastslam_kernels import associate_ml

            model = self.measurement_model
            offset = np.asarray(getattr(model, "sensor_offset", (0.0, 0.0, 0.0)), np.float64)
            associate_ml(np.ascontiguousarray(poses), offset, mean, cov, found,
                         np.ascontiguousarray(zs), self._R, self._Rt, v2, self._log_p0,
                         float(self.config.visibility_range),
                         0.5 * float(self.config.visibility_fov), cols, unseen)  # fmt: skip
            new = cols < 0
        else:
            new[:] = True
        for i in range(k):  # new landmarks take each particle's next free column
            cols[i, new[i]] = self._next_col[new[i]]
            self._next_col[new[i]] += 1
        self.store.ensure_cols(int(self._next_col.max()))
        return cols, new, unseen

    def _count_misses(self, unseen: BoolArray) -> None:
        """Table 13.2 lines 28-33: a landmark in the perceptual range and not observed loses
        one from its counter, and is removed below 0."""
        for c in np.flatnonzero(unseen.any(axis=0)):
            cols = np.where(unseen[:, c], c, -1)
            mean, cov, count, found = self.store.gather(cols)
            count = count - 1
            gone = found & (count < 0)
            self.store.scatter(np.where(found & ~gone, cols, -1), mean, cov, count)
            self.store.clear(np.where(gone, cols, -1))

    def _measurement_step(self, zs: FloatArray, colmat: IntArray, unknown: bool) -> FloatArray:
        """Proposal (2.0), landmark updates and importance factors of one step, in the
        :func:`~probmap.slam.landmark._fastslam_kernels.fastslam_update` kernel: the landmarks of
        ``colmat (k, M)`` (-1: none) are read from the store, updated and written back."""
        from probmap.slam.landmark._fastslam_kernels import fastslam_update

        k, m = colmat.shape[0], len(self.particles)
        mean, cov = np.empty((k, m, 2)), np.empty((k, m, 2, 2))
        count, found = np.empty((k, m), dtype=np.int64), np.empty((k, m), dtype=bool)
        for i in range(k):
            mean[i], cov[i], count[i], found[i] = self.store.gather(colmat[i])
        active = colmat >= 0
        mode = np.where(active & found, 1, np.where(active, 2, 0)).astype(np.int64)
        v2 = self.config.version == 2 and bool(self._Rt.any())
        # 2.0 draws every particle's pose each step (Table 13.3 line 15), observations or not
        noise = self._rng.standard_normal((m, 3)) if v2 else np.zeros((m, 3))
        offset = np.asarray(
            getattr(self.measurement_model, "sensor_offset", (0.0, 0.0, 0.0)), dtype=np.float64
        )
        logw = np.zeros(m)
        self.particles = np.ascontiguousarray(self.particles, dtype=np.float64)
        fastslam_update(self.particles, np.ascontiguousarray(self._predicted), self._Rt, v2,
                        np.ascontiguousarray(zs), self._R, offset,
                        np.ascontiguousarray(colmat), mode, mean, cov, count, noise,
                        self._log_p0 if unknown else 0.0, logw)  # fmt: skip
        for i in range(k):  # in order: a landmark observed twice keeps the later result
            self.store.scatter(np.where(active[i], colmat[i], -1), mean[i], cov[i], count[i])
        return logw

    def state_nbytes(self) -> int:
        """Bytes of the filter's state: particle poses and weights and the landmark store
        (``O(M N)`` flat; the tree's nodes in use, ``O(N + M log N)`` per step's changes)."""
        return int(self.particles.nbytes + self.log_weights.nbytes + self.store.nbytes())

    # ------------------------------------------------------------------ estimates
    def _weights(self) -> FloatArray:
        w = np.exp(self.log_weights - self.log_weights.max())
        return w / w.sum()

    @property
    def pose(self) -> FloatArray:
        """Weighted mean pose (3,), the heading as a circular mean."""
        w = self._weights()
        p = self.particles
        th = math.atan2(float(w @ np.sin(p[:, 2])), float(w @ np.cos(p[:, 2])))
        return np.array([float(w @ p[:, 0]), float(w @ p[:, 1]), th])

    @property
    def pose_covariance(self) -> FloatArray:
        """Weighted covariance (3, 3) of the particles around :attr:`pose`."""
        w = self._weights()
        d = self.particles - self.pose
        d[:, 2] = wrap_angle(d[:, 2])
        return np.einsum("n,ni,nj->ij", w, d, d) + 1e-12 * np.eye(3)

    @property
    def n_landmarks(self) -> int:
        """Landmarks the heaviest particle holds (provisional ones included)."""
        best = np.array([int(np.argmax(self.log_weights))])
        return int(self.store.dense(best)[3].sum())

    def landmarks(self) -> tuple[IntArray, FloatArray, FloatArray]:
        """The heaviest particle's landmarks: ``ids (n,)``, ``xy (n, 2)``, ``cov (n, 2, 2)``.
        With unknown correspondences the ids are the particle's columns, and only landmarks
        whose counter reached ``min_count`` are reported."""
        best = np.array([int(np.argmax(self.log_weights))])
        mean, cov, count, found = (a[0] for a in self.store.dense(best))
        if self._known is False:
            keep = np.flatnonzero(found & (count >= self.config.min_count))
            return keep.astype(np.int64), mean[keep], cov[keep]
        ids = np.asarray(sorted(self._slot, key=self._slot.__getitem__), dtype=np.int64)
        cols = np.asarray([self._slot[int(i)] for i in ids], dtype=np.int64)
        seen = found[cols] if cols.size else np.zeros(0, dtype=bool)
        return ids[seen], mean[cols[seen]], cov[cols[seen]]
