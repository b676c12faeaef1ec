"""FastSLAM 1.0 and 2.0 with known correspondences (Probabilistic Robotics ch. 13, Tables 13.1
and 13.3): a particle filter over robot paths, each particle carrying one small EKF per
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

Landmark arrays are copied on resampling (``O(M L)``), not shared in the book's balanced tree
(``O(M log L)``): for the tens of landmarks of the datasets here that is the faster choice.
Unknown correspondences (Table 13.2's maximum-likelihood association with a new-landmark
likelihood) are not implemented: ``update`` refuses measurements with ``id < 0``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from probmap._typing import FloatArray, IntArray
from probmap.filters.resampling import effective_sample_size, low_variance_resample
from probmap.geometry.se2 import compose, wrap_angle

__all__ = ["FastSLAM", "FastSLAMConfig"]


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
    """

    n_particles: int = 100
    version: int = 2
    resample_threshold: float = 0.5
    seed: int = 0

    def __post_init__(self) -> None:
        if self.n_particles < 1:
            raise ValueError(f"n_particles must be >= 1, got {self.n_particles}")
        if self.version not in (1, 2):
            raise ValueError(f"version must be 1 or 2, got {self.version}")
        if not 0.0 <= self.resample_threshold <= 1.0:
            raise ValueError(
                f"resample_threshold must lie in [0, 1], got {self.resample_threshold}"
            )


def _batch_measurement(
    model: Any, poses: FloatArray, landmarks: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Range-bearing ``h`` for one landmark per pose: poses (M, 3), landmarks (M, 2) ->
    ``z (M, 2)``, ``H_x (M, 2, 3)``, ``H_m (M, 2, 2)`` (the model's sensor offset included)."""
    spos, ds, heading = model._sensor(poses)
    d = landmarks - spos
    q = np.maximum(np.einsum("ij,ij->i", d, d), 1e-18)
    r = np.sqrt(q)
    z = np.stack([r, wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - heading)], -1)
    H_m = np.empty((len(poses), 2, 2))
    H_m[:, 0, 0] = d[:, 0] / r
    H_m[:, 0, 1] = d[:, 1] / r
    H_m[:, 1, 0] = -d[:, 1] / q
    H_m[:, 1, 1] = d[:, 0] / q
    H_x = np.empty((len(poses), 2, 3))
    H_x[:, :, :2] = -H_m
    H_x[:, :, 2] = -np.einsum("nij,nj->ni", H_m, ds)
    H_x[:, 1, 2] -= 1.0
    return z, H_x, H_m


def _gauss_logpdf(e: FloatArray, S: FloatArray) -> FloatArray:
    """log N(e; 0, S) for e (M, 2), S (M, 2, 2)."""
    det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
    inv = (
        np.stack(
            [np.stack([S[:, 1, 1], -S[:, 0, 1]], -1), np.stack([-S[:, 1, 0], S[:, 0, 0]], -1)], 1
        )
        / det[:, None, None]
    )
    m = np.einsum("ni,nij,nj->n", e, inv, e)
    return -0.5 * m - 0.5 * np.log(det) - math.log(2.0 * math.pi)


class FastSLAM:
    """FastSLAM 1.0 / 2.0 with known correspondences (a :class:`LandmarkSLAM
    <probmap.slam.base.LandmarkSLAM>`: ``predict`` then ``update`` each step).

    Parameters
    ----------
    motion_model : VelocityModel or AckermannModel
        ``predict(x, u, dt) -> (x_new, G, V)`` and ``control_covariance(u, dt)``.
    measurement_model : RangeBearingModel
        ``R`` and the sensor offset.
    initial_pose : array_like, shape (3,)
        Every particle starts here (the map frame is the first pose's, as for the EKF).
    config : FastSLAMConfig, optional

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
        self._slot: dict[int, int] = {}  # landmark id -> column of the landmark arrays
        self._mean = np.zeros((m, 0, 2))
        self._cov = np.zeros((m, 0, 2, 2))
        self._seen = np.zeros((m, 0), dtype=bool)
        self._Rt = np.zeros((3, 3))  # motion noise of the last prediction (2.0's proposal)
        self._predicted = self.particles.copy()
        self.resamples = 0

    # ------------------------------------------------------------------ steps
    def predict(self, u: ArrayLike, dt: float) -> None:
        """Motion: every particle moves by the displacement of a noisy control."""
        u = np.asarray(u, dtype=np.float64)
        if u.shape != (2,) or not np.all(np.isfinite(u)):
            raise ValueError(f"control must be 2 finite numbers, got {u!r}")
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
        """Measurements ``z (k, 2)`` of landmarks ``ids (k,)`` (all >= 0)."""
        zs = np.asarray(z, dtype=np.float64).reshape(-1, 2)
        idx = np.asarray(ids, dtype=np.int64).reshape(-1)
        if zs.shape[0] != idx.shape[0]:
            raise ValueError(f"z has {zs.shape[0]} rows and ids {idx.shape[0]}")
        if zs.size and not np.all(np.isfinite(zs)):
            raise ValueError("measurements must be finite")
        if np.any(idx < 0):
            raise ValueError(
                "FastSLAM here needs known correspondences (ids >= 0); an id of -1 (unknown) "
                "is not supported yet"
            )
        for j in idx:
            if int(j) not in self._slot:
                self._add_slot(int(j))
        cols = np.asarray([self._slot[int(j)] for j in idx], dtype=np.int64)
        if self.config.version == 2 and self._Rt.any():
            self._propose(zs, cols)
        logw = np.zeros(len(self.particles))
        for zk, c in zip(zs, cols, strict=True):
            logw += self._landmark_update(zk, int(c))
        self.log_weights += logw
        self.log_weights -= self.log_weights.max()
        w = np.exp(self.log_weights)
        w /= w.sum()
        if effective_sample_size(w) < self.config.resample_threshold * len(w):
            keep = low_variance_resample(w, self._rng)
            self.particles = self.particles[keep]
            self._mean = self._mean[keep]
            self._cov = self._cov[keep]
            self._seen = self._seen[keep]
            self.log_weights = np.zeros(len(keep))
            self.resamples += 1

    def _add_slot(self, landmark_id: int) -> None:
        m = len(self.particles)
        self._slot[landmark_id] = self._mean.shape[1]
        self._mean = np.concatenate([self._mean, np.zeros((m, 1, 2))], 1)
        self._cov = np.concatenate([self._cov, np.zeros((m, 1, 2, 2))], 1)
        self._seen = np.concatenate([self._seen, np.zeros((m, 1), dtype=bool)], 1)

    def _propose(self, zs: FloatArray, cols: IntArray) -> None:
        """FastSLAM 2.0: draw each particle's pose from the Gaussian updated by the step's
        measurements of landmarks it has seen (Table 13.3 lines 6-14); 2.0's weights (line
        16) use the prior ``R_t`` and are taken in :meth:`_landmark_update`."""
        x = self._predicted.copy()  # mean of the proposal, per particle
        P = np.repeat(self._Rt[None, :, :] + 1e-12 * np.eye(3), len(x), axis=0)
        model = self.measurement_model
        for zk, c in zip(zs, cols, strict=True):
            seen = self._seen[:, c]
            if not seen.any():
                continue
            xs, Ps = x[seen], P[seen]
            zh, H_x, H_m = _batch_measurement(model, xs, self._mean[seen, c])
            S = self._R + np.einsum("nij,njk,nlk->nil", H_m, self._cov[seen, c], H_m)
            innov = zk - zh
            innov[:, 1] = wrap_angle(innov[:, 1])
            PHt = np.einsum("nij,nkj->nik", Ps, H_x)
            T = np.einsum("nij,njk->nik", H_x, PHt) + S
            K = np.einsum("nij,njk->nik", PHt, np.linalg.inv(T))
            x[seen] = xs + np.einsum("nij,nj->ni", K, innov)
            x[seen, 2] = wrap_angle(x[seen, 2])
            P[seen] = Ps - np.einsum("nij,njk->nik", K, np.transpose(PHt, (0, 2, 1)))
        P = 0.5 * (P + np.transpose(P, (0, 2, 1)))
        L = np.linalg.cholesky(P + 1e-15 * np.eye(3))
        e = self._rng.standard_normal((len(x), 3))
        self.particles = x + np.einsum("nij,nj->ni", L, e)
        self.particles[:, 2] = wrap_angle(self.particles[:, 2])

    def _landmark_update(self, zk: FloatArray, c: int) -> FloatArray:
        """One measurement of landmark column ``c`` for every particle: initialize where it
        is new, EKF-update where it is known; returns each particle's log importance factor."""
        model = self.measurement_model
        logw = np.zeros(len(self.particles))
        new = ~self._seen[:, c]
        if new.any():
            poses = self.particles[new]
            spos, _, heading = model._sensor(poses)
            a = heading + zk[1]
            ca, sa = np.cos(a), np.sin(a)
            self._mean[new, c] = spos + zk[0] * np.stack([ca, sa], -1)
            Jz = np.empty((len(poses), 2, 2))
            Jz[:, 0, 0], Jz[:, 0, 1] = ca, -zk[0] * sa
            Jz[:, 1, 0], Jz[:, 1, 1] = sa, zk[0] * ca
            self._cov[new, c] = np.einsum("nij,jk,nlk->nil", Jz, self._R, Jz)
            self._seen[new, c] = True
        old = ~new
        if old.any():
            poses = self.particles[old]
            mu, Sig = self._mean[old, c], self._cov[old, c]
            zh, H_x, H_m = _batch_measurement(model, poses, mu)
            Q = self._R + np.einsum("nij,njk,nlk->nil", H_m, Sig, H_m)
            innov = zk - zh
            innov[:, 1] = wrap_angle(innov[:, 1])
            K = np.einsum("nij,nkj,nkl->nil", Sig, H_m, np.linalg.inv(Q))
            self._mean[old, c] = mu + np.einsum("nij,nj->ni", K, innov)
            cov = Sig - np.einsum("nij,njk,nkl->nil", K, H_m, Sig)
            self._cov[old, c] = 0.5 * (cov + np.transpose(cov, (0, 2, 1)))
            if self.config.version == 2 and self._Rt.any():
                # Table 13.3 line 16: the measurement's likelihood under the proposal's prior
                zp, Hp, _ = _batch_measurement(model, self._predicted[old], mu)
                e = zk - zp
                e[:, 1] = wrap_angle(e[:, 1])
                L = Q + np.einsum("nij,jk,nlk->nil", Hp, self._Rt, Hp)
                logw[old] = _gauss_logpdf(e, L)
            else:
                logw[old] = _gauss_logpdf(innov, Q)
        return logw

    def state_nbytes(self) -> int:
        """Bytes of the filter's state: particle poses and weights, every particle's landmark
        means, covariances and seen flags (``O(M L)``)."""
        arrays = (self.particles, self.log_weights, self._mean, self._cov, self._seen)
        return int(sum(a.nbytes for a in arrays))

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

    def landmarks(self) -> tuple[IntArray, FloatArray, FloatArray]:
        """The heaviest particle's landmarks: ``ids (n,)``, ``xy (n, 2)``, ``cov (n, 2, 2)``."""
        best = int(np.argmax(self.log_weights))
        ids = np.asarray(sorted(self._slot, key=self._slot.__getitem__), dtype=np.int64)
        cols = np.asarray([self._slot[int(i)] for i in ids], dtype=np.int64)
        seen = self._seen[best, cols] if cols.size else np.zeros(0, dtype=bool)
        return ids[seen], self._mean[best, cols[seen]], self._cov[best, cols[seen]]
