"""Monte Carlo localization (Probabilistic Robotics chapter 8).

- :class:`MonteCarloLocalization`: MCL (Table 8.2) with log-domain weights, low-variance
  resampling when the effective sample size is low, augmented MCL (Table 8.3: random
  particles injected while the short-term average likelihood ``w_fast`` falls below the
  long-term one ``w_slow``) and optional KLD-sampling (Table 8.4).
- Sensors: anything with ``log_likelihood_sum(poses, *z) -> (N,)``; the grid models of
  :mod:`probmap.grid.forward` and :class:`RangeBearingLandmarks` (known correspondences,
  Table 6.4) fit. With a :class:`~probmap.grid.forward.LikelihoodField` and an
  :class:`~probmap.models.sampling.OdometryMotionModel`, :meth:`MonteCarloLocalization.update_scan`
  runs motion sampling and weighting in one compiled pass.
- Motion: anything with ``sample(poses, *u, rng) -> (N, 3)`` (both models of
  :mod:`probmap.models.sampling` fit).

Poses are ``(x, y, theta)`` in the map frame (m, rad).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap.filters import _kernels as _k
from probmap.filters.kld import KLDConfig, kld_resample
from probmap.filters.particle import (
    ParticleFilterWarning,
    weighted_pose_covariance,
    weighted_pose_mean,
)
from probmap.grid.forward import GridGeometry, LikelihoodField
from probmap.models.sampling import OdometryMotionModel, odometry_deltas, odometry_noise_std

__all__ = [
    "FreeSpaceSampler",
    "MCLConfig",
    "MonteCarloLocalization",
    "PoseEstimate",
    "RangeBearingLandmarks",
]


class MotionModel(Protocol):
    def sample(self, poses: Any, *args: Any) -> NDArray[np.float64]: ...


class SensorModel(Protocol):
    def log_likelihood_sum(self, poses: Any, *z: Any) -> NDArray[np.float64]: ...


@dataclass(frozen=True)
class MCLConfig:
    """Monte Carlo localization settings.

    Parameters
    ----------
    n_particles : int
        Particle count (the initial count under KLD-sampling).
    resample_threshold : float
        Resample when ESS < ``resample_threshold * N``; 1.0 resamples every update.
    augmented : bool
        Inject random particles from ``w_slow``/``w_fast`` (Table 8.3).
    alpha_slow, alpha_fast : float
        Decay rates of the long- and short-term likelihood averages,
        ``0 <= alpha_slow << alpha_fast``.
    kld : KLDConfig or None
        Adaptive particle count (Table 8.4) when given.
    cluster_size : float
        Cell size (m) for the best-cluster estimate.
    """

    n_particles: int = 1000
    resample_threshold: float = 0.5
    augmented: bool = False
    alpha_slow: float = 0.001
    alpha_fast: float = 0.1
    kld: KLDConfig | None = None
    cluster_size: float = 0.5

    def __post_init__(self) -> None:
        if self.n_particles <= 0:
            raise ValueError(f"n_particles must be positive, got {self.n_particles}")
        if not 0.0 <= self.resample_threshold <= 1.0:
            raise ValueError(f"resample_threshold must be in [0, 1], got {self.resample_threshold}")
        if not 0.0 <= self.alpha_slow < self.alpha_fast <= 1.0:
            raise ValueError(
                f"need 0 <= alpha_slow < alpha_fast <= 1, got {self.alpha_slow}, {self.alpha_fast}"
            )
        if not self.cluster_size > 0:
            raise ValueError(f"cluster_size must be positive, got {self.cluster_size}")


@dataclass(frozen=True)
class PoseEstimate:
    """Summary of the particle set.

    Attributes
    ----------
    mean : (3,) ndarray
        Weighted mean (circular mean for theta).
    covariance : (3, 3) ndarray
        Weighted covariance (heading residuals wrapped).
    best_cluster : (3,) ndarray
        Weighted mean of the heaviest cluster (xy cells of ``cluster_size``, merged with
        neighbours within one cell).
    cluster_weight : float
        Total weight of that cluster.
    n_particles : int
    ess : float
        Effective sample size before resampling.
    """

    mean: NDArray[np.float64]
    covariance: NDArray[np.float64]
    best_cluster: NDArray[np.float64]
    cluster_weight: float
    n_particles: int
    ess: float

    @property
    def spread(self) -> float:
        """``sqrt(var_x + var_y)`` (m): the particle cloud's positional spread."""
        return float(math.sqrt(max(self.covariance[0, 0] + self.covariance[1, 1], 0.0)))


class FreeSpaceSampler:
    """Uniform poses over the free cells of a grid (heading uniform in ``[-pi, pi)``).

    Parameters
    ----------
    spec : GridGeometry
        Grid geometry.
    free : (H, W) bool array_like
        True where the robot may be.
    """

    def __init__(self, spec: GridGeometry, free: ArrayLike) -> None:
        f = np.asarray(free, dtype=bool)
        shape = tuple(int(v) for v in spec.shape)
        if f.shape != shape:
            raise ValueError(f"free mask shape {f.shape} does not match spec shape {shape}")
        self.cells = np.flatnonzero(f)
        if self.cells.size == 0:
            raise ValueError("the map has no free cell to place particles in")
        self.width = shape[1]
        self.resolution = float(spec.resolution)
        self.x0, self.y0 = (float(v) for v in spec.origin)

    def sample(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """``(n, 3)`` poses uniform over free space."""
        c = self.cells[rng.integers(0, self.cells.size, size=n)]
        iy, ix = np.divmod(c, self.width)
        out = np.empty((n, 3))
        out[:, 0] = self.x0 + (ix + rng.uniform(size=n)) * self.resolution
        out[:, 1] = self.y0 + (iy + rng.uniform(size=n)) * self.resolution
        out[:, 2] = rng.uniform(-np.pi, np.pi, size=n)
        return out


@dataclass(frozen=True)
class RangeBearingLandmarks:
    """Range-bearing measurements of known landmarks (known correspondences, Table 6.4).

    Parameters
    ----------
    ids : (L,) int array
        Landmark identifiers.
    positions : (L, 2) float array
        Landmark positions (m) in the map frame.
    sigma_range : float
        Range noise standard deviation (m).
    sigma_bearing : float
        Bearing noise standard deviation (rad).
    outlier_probability : float
        Mixture weight of a uniform outlier component over ``[0, max_range] x [-pi, pi)``
        (0 gives the book's pure Gaussian model). A few percent keeps one bad detection from
        collapsing the particle set.
    max_range : float
        Range (m) over which outliers are uniform.
    """

    ids: NDArray[np.int64]
    positions: NDArray[np.float64]
    sigma_range: float = 0.1
    sigma_bearing: float = 0.05
    outlier_probability: float = 0.0
    max_range: float = 20.0
    _lookup: dict[int, int] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        ids = np.asarray(self.ids, dtype=np.int64)
        pos = np.asarray(self.positions, dtype=np.float64)
        if ids.ndim != 1 or pos.shape != (ids.size, 2) or not np.all(np.isfinite(pos)):
            raise ValueError(
                f"ids must be (L,) and positions finite (L, 2): {ids.shape}, {pos.shape}"
            )
        if not (self.sigma_range > 0 and self.sigma_bearing > 0):
            raise ValueError("sigma_range and sigma_bearing must be positive")
        if not (0.0 <= self.outlier_probability < 1.0 and self.max_range > 0):
            raise ValueError("need 0 <= outlier_probability < 1 and max_range > 0")
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "_lookup", {int(i): k for k, i in enumerate(ids)})

    def log_likelihood(self, poses: ArrayLike, z: ArrayLike, ids: ArrayLike) -> NDArray[np.float64]:
        """Per-measurement log-likelihoods ``(N, k)``.

        Parameters
        ----------
        poses : (N, 3) array_like
            Robot poses.
        z : (k, 2) array_like
            Measured (range m, bearing rad) in the robot frame.
        ids : (k,) array_like
            Landmark id of each measurement; unknown ids raise ``ValueError``.
        """
        p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        zz = np.asarray(z, dtype=np.float64).reshape(-1, 2)
        idx = np.asarray(ids).reshape(-1)
        if idx.shape[0] != zz.shape[0]:
            raise ValueError(f"{zz.shape[0]} measurements but {idx.shape[0]} ids")
        try:
            rows = np.array([self._lookup[int(i)] for i in idx], dtype=np.int64)
        except KeyError as exc:
            raise ValueError(f"measurement of unknown landmark id {exc.args[0]}") from None
        lm = self.positions[rows]
        dx = lm[None, :, 0] - p[:, None, 0]
        dy = lm[None, :, 1] - p[:, None, 1]
        r_hat = np.hypot(dx, dy)
        b_hat = np.arctan2(dy, dx) - p[:, None, 2]
        er = (zz[None, :, 0] - r_hat) / self.sigma_range
        eb = ((zz[None, :, 1] - b_hat + np.pi) % (2 * np.pi) - np.pi) / self.sigma_bearing
        norm = math.log(2 * math.pi * self.sigma_range * self.sigma_bearing)
        ll = -0.5 * (er * er + eb * eb) - norm
        eps = self.outlier_probability
        if eps > 0.0:
            uniform = -math.log(self.max_range * 2 * math.pi)
            ll = np.logaddexp(math.log1p(-eps) + ll, math.log(eps) + uniform)
        return np.asarray(ll)

    def log_likelihood_sum(
        self, poses: ArrayLike, z: ArrayLike, ids: ArrayLike
    ) -> NDArray[np.float64]:
        """Log-likelihood of all measurements, ``(N,)``."""
        return np.asarray(self.log_likelihood(poses, z, ids).sum(axis=1))


class MonteCarloLocalization:
    """Monte Carlo localization, Tables 8.2-8.4.

    Parameters
    ----------
    sensor : SensorModel
        Measurement model with ``log_likelihood_sum(poses, *z)``.
    motion : MotionModel
        Motion model with ``sample(poses, *u, rng)``.
    rng : numpy.random.Generator
    config : MCLConfig
    free_space : FreeSpaceSampler, optional
        Needed for global localization, augmented MCL and recovery from all-zero weights.
    """

    def __init__(
        self,
        sensor: SensorModel,
        motion: MotionModel,
        rng: np.random.Generator,
        config: MCLConfig | None = None,
        free_space: FreeSpaceSampler | None = None,
    ) -> None:
        self.config = config or MCLConfig()
        if self.config.augmented and free_space is None:
            raise ValueError("augmented MCL needs a free_space sampler for random particles")
        self.sensor = sensor
        self.motion = motion
        self.rng = rng
        self.free_space = free_space
        n = self.config.n_particles
        self.particles = np.zeros((n, 3))
        self.log_weights = np.full(n, -math.log(n))
        self.w_slow = 0.0
        self.w_fast = 0.0
        self.last_ess = float(n)

    # -- initialisation -------------------------------------------------------------------
    def initialize_pose(self, mean: ArrayLike, covariance: ArrayLike) -> None:
        """Tracking: particles from a Gaussian around a known start pose."""
        mu = np.asarray(mean, dtype=np.float64)
        cov = np.asarray(covariance, dtype=np.float64)
        if mu.shape != (3,) or cov.shape != (3, 3):
            raise ValueError(
                f"mean must be (3,) and covariance (3, 3), got {mu.shape}, {cov.shape}"
            )
        n = self.config.n_particles
        p = self.rng.multivariate_normal(mu, cov, size=n, method="eigh")
        p[:, 2] = (p[:, 2] + np.pi) % (2 * np.pi) - np.pi
        self._reset(p)

    def initialize_global(self) -> None:
        """Global localization: particles uniform over free space."""
        if self.free_space is None:
            raise ValueError("global localization needs a free_space sampler")
        self._reset(self.free_space.sample(self.config.n_particles, self.rng))

    def _reset(self, particles: NDArray[np.float64]) -> None:
        self.particles = np.ascontiguousarray(particles, dtype=np.float64)
        n = self.particles.shape[0]
        self.log_weights = np.full(n, -math.log(n))
        self.last_ess = float(n)

    @property
    def n(self) -> int:
        return int(self.particles.shape[0])

    @property
    def weights(self) -> NDArray[np.float64]:
        w = np.exp(self.log_weights - self.log_weights.max())
        return np.asarray(w / w.sum())

    # -- algorithm steps --------------------------------------------------------------------
    def predict(self, *u: Any) -> None:
        """Sample the motion model for every particle (Table 8.2, line 4)."""
        self.particles = np.ascontiguousarray(self.motion.sample(self.particles, *u, self.rng))

    def correct(self, *z: Any) -> None:
        """Weight every particle by the measurement model (Table 8.2, line 5)."""
        ll = np.asarray(self.sensor.log_likelihood_sum(self.particles, *z), dtype=np.float64)
        if ll.shape != (self.n,):
            raise ValueError(f"sensor returned shape {ll.shape}, expected ({self.n},)")
        self._add_log_likelihood(ll, _measurement_count(z))

    def _add_log_likelihood(self, ll: NDArray[np.float64], count: int) -> None:
        lw = np.where(np.isnan(ll), -np.inf, self.log_weights + ll)
        top = float(lw.max())
        if not math.isfinite(top):
            self._recover()
            return
        if self.config.augmented:
            # Table 8.3 lines 6-10 on the per-measurement geometric mean likelihood, so the
            # averages stay in floating-point range whatever the number of beams.
            log_avg = (float(np.log(np.exp(ll - ll.max()).mean())) + float(ll.max())) / max(
                count, 1
            )
            w_avg = math.exp(min(log_avg, 700.0))
            if self.w_slow == 0.0:
                self.w_slow = self.w_fast = w_avg
            self.w_slow += self.config.alpha_slow * (w_avg - self.w_slow)
            self.w_fast += self.config.alpha_fast * (w_avg - self.w_fast)
        w = np.exp(lw - top)
        s = float(w.sum())
        with np.errstate(divide="ignore"):
            self.log_weights = lw - top - math.log(s)
        w /= s
        self.last_ess = float(1.0 / np.dot(w, w))

    def _recover(self) -> None:
        if self.free_space is not None:
            msg = "every particle has zero likelihood; particles reinitialised over free space"
            self._reset(self.free_space.sample(self.n, self.rng))
        else:
            msg = "every particle has zero likelihood; measurement ignored, weights reset"
            self.log_weights = np.full(self.n, -math.log(self.n))
        warnings.warn(msg, ParticleFilterWarning, stacklevel=3)

    def random_fraction(self) -> float:
        """Probability of a random particle, ``max(0, 1 - w_fast / w_slow)`` (Table 8.3)."""
        if not self.config.augmented or self.w_slow <= 0.0:
            return 0.0
        return max(0.0, 1.0 - self.w_fast / self.w_slow)

    def resample(self) -> None:
        """Low-variance resampling (Table 4.4), KLD-sampling when configured (Table 8.4),
        with random particles injected under augmented MCL (Table 8.3)."""
        w = self.weights
        if self.config.kld is not None:
            idx = kld_resample(self.particles, w, self.rng, self.config.kld)
        else:
            idx = np.empty(self.n, dtype=np.int64)
            _k.low_variance_indexes(w, float(self.rng.uniform()), idx)
        new = np.empty((idx.shape[0], 3))
        _k.gather_rows(self.particles, idx, new)
        p_rand = self.random_fraction()
        if p_rand > 0.0 and self.free_space is not None:
            k = int(self.rng.binomial(new.shape[0], p_rand))
            if k:
                slots = self.rng.choice(new.shape[0], size=k, replace=False)
                new[slots] = self.free_space.sample(k, self.rng)
        self._reset(new)

    def resample_if_needed(self) -> bool:
        """Resample when ESS < ``resample_threshold * N`` (always, when augmented MCL wants
        random particles); return whether it did."""
        if self.last_ess < self.config.resample_threshold * self.n or self.random_fraction() > 0:
            self.resample()
            return True
        return False

    def update(self, u: tuple[Any, ...], z: tuple[Any, ...]) -> PoseEstimate:
        """One MCL step: predict with ``u``, correct with ``z``, estimate, resample if needed."""
        self.predict(*u)
        self.correct(*z)
        est = self.estimate()
        self.resample_if_needed()
        return est

    def update_scan(
        self,
        odom_prev: ArrayLike,
        odom_cur: ArrayLike,
        ranges: ArrayLike,
        angles: ArrayLike,
        sensor_offset: ArrayLike = (0.0, 0.0, 0.0),
    ) -> PoseEstimate:
        """One MCL step with odometry and a range scan.

        With a likelihood field and the odometry model, sampling (Table 5.6) and weighting
        (Table 6.3) run fused in one compiled pass; otherwise :meth:`update` is used.
        """
        if not (
            isinstance(self.sensor, LikelihoodField)
            and isinstance(self.motion, OdometryMotionModel)
        ):
            return self.update((odom_prev, odom_cur), (ranges, angles, sensor_offset))
        lf, mm = self.sensor, self.motion
        lx, ly, valid = lf.endpoints(ranges, angles, sensor_offset)
        self.predict_and_weight(odom_prev, odom_cur, lx[valid], ly[valid], lf, mm)
        est = self.estimate()
        self.resample_if_needed()
        return est

    def predict_and_weight(
        self,
        odom_prev: ArrayLike,
        odom_cur: ArrayLike,
        lx: NDArray[np.float64],
        ly: NDArray[np.float64],
        lf: LikelihoodField,
        mm: OdometryMotionModel,
    ) -> None:
        """Fused odometry sampling + likelihood-field weighting for valid endpoints ``lx, ly``."""
        r1, tr, r2 = (float(v) for v in odometry_deltas(odom_prev, odom_cur))
        sd1, sdt, sd2 = odometry_noise_std(r1, tr, r2, mm.alphas)
        noise = self.rng.standard_normal((self.n, 3))
        ll = np.zeros(self.n)
        f = lf.frame
        _k.odometry_predict_and_weight(
            self.particles,
            noise,
            r1,
            tr,
            r2,
            sd1,
            sdt,
            sd2,
            np.ascontiguousarray(lx),
            np.ascontiguousarray(ly),
            lf.table,
            f.x0,
            f.y0,
            1.0 / f.resolution,
            lf.outside,
            ll,
        )
        self._add_log_likelihood(ll, int(lx.shape[0]))

    # -- estimates ----------------------------------------------------------------------------
    def estimate(self) -> PoseEstimate:
        """Weighted mean and covariance, and the heaviest cluster's mean."""
        w = self.weights
        mean = weighted_pose_mean(self.particles, w)
        cov = weighted_pose_covariance(self.particles, w, mean)
        best, cw = self._best_cluster(w)
        return PoseEstimate(mean, cov, best, cw, self.n, self.last_ess)

    def _best_cluster(self, w: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
        size = self.config.cluster_size
        cells = np.floor(self.particles[:, :2] / size).astype(np.int64)
        lo = cells.min(axis=0)
        span = cells.max(axis=0) - lo + 1
        flat = (cells[:, 0] - lo[0]) * span[1] + (cells[:, 1] - lo[1])
        if span[0] * span[1] <= 4 * flat.size + 1024:
            mass = np.bincount(flat, weights=w)
            best = int(np.argmax(mass))
        else:  # particles spread thinly over a large area: only the occupied cells
            keys, inverse = np.unique(flat, return_inverse=True)
            best = int(keys[int(np.argmax(np.bincount(inverse.reshape(-1), weights=w)))])
        top = np.array([best // span[1] + lo[0], best % span[1] + lo[1]])
        # Merge the 3x3 neighbourhood so a cluster split by a cell border stays whole.
        near = np.all(np.abs(cells - top) <= 1, axis=1)
        wc = w[near]
        total = float(wc.sum())
        return weighted_pose_mean(self.particles[near], wc / total), total


def _measurement_count(z: tuple[Any, ...]) -> int:
    if not z:
        return 1
    try:
        first = np.asarray(z[0])
    except (TypeError, ValueError):
        return 1
    return int(first.shape[0]) if first.ndim >= 1 else 1
