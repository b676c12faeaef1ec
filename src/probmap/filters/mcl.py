"""Monte Carlo localization (Probabilistic Robotics chapter 8).

- :class:`MonteCarloLocalization`: MCL (Table 8.2) with log-domain weights, low-variance
  resampling when the effective sample size is low, augmented MCL (Table 8.3: random
  particles injected while the short-term average likelihood ``w_fast`` falls below the
  long-term one ``w_slow``) and optional KLD-sampling (Table 8.4).
- Sensors: anything with ``log_likelihood_sum(poses, *z) -> (N,)``; the grid models of
  :mod:`probmap.models` and :class:`RangeBearingLandmarks` (known correspondences,
  Table 6.4) fit. With a :class:`~probmap.models.likelihood_field.LikelihoodField` and an
  :class:`~probmap.models.sampling.OdometryMotionModel`, :meth:`MonteCarloLocalization.update_scan`
  runs motion sampling and weighting in one compiled pass.
- Motion: anything with ``sample(poses, *u, rng) -> (N, 3)`` (both models of
  :mod:`probmap.models.sampling` fit).

Poses are ``(x, y, theta)`` in the map frame (m, rad).

Two tiers, as in :mod:`probmap.slam.landmark.seif`: array functions that state Table 8.2's steps
(:func:`mcl_sample_motion`, line 4; :func:`mcl_weight`, line 5 with normalisation;
:func:`mcl_resample`, lines 8-11 with Tables 4.4, 8.3 and 8.4; :func:`mcl_likelihood_averages`
and :func:`mcl_random_fraction`, Table 8.3; :func:`mcl_sample_and_weight_scan`, the fused
odometry + likelihood-field pass; :func:`sample_pose_gaussian`, the tracking prior), and the
stateful :class:`MonteCarloLocalization`, which holds the particle set and calls them.

A filter is valid as soon as it is built: give the initial particle set
(``MonteCarloLocalization(..., particles=p)``) or use :meth:`MonteCarloLocalization.from_pose`
(tracking) or :meth:`MonteCarloLocalization.uniform` (global localization).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap.filters import _kernels as _k
from probmap.filters.clusters import Hypothesis, particle_clusters
from probmap.filters.kld import KLDConfig, kld_count
from probmap.filters.mcl_robust import mcl_sample_and_weight_robust as _robust
from probmap.filters.particle import (
    ParticleFilterWarning,
    weighted_pose_covariance,
    weighted_pose_mean,
)
from probmap.geometry.se2 import wrap_angle
from probmap.models.grid_map import GridGeometry
from probmap.models.likelihood_field import LikelihoodField
from probmap.models.sampling import OdometryMotionModel, odometry_deltas, odometry_noise_std

__all__ = [
    "FreeSpaceSampler",
    "Hypothesis",
    "MCLConfig",
    "MonteCarloLocalization",
    "MotionModel",
    "PoseEstimate",
    "RangeBearingLandmarks",
    "SensorModel",
    "mcl_adaptive_exponent",
    "mcl_likelihood_averages",
    "mcl_likelihood_exponent",
    "mcl_random_fraction",
    "mcl_resample",
    "mcl_sample_and_weight_scan",
    "mcl_sample_motion",
    "mcl_weight",
    "particle_clusters",
    "sample_pose_gaussian",
]


class MotionModel(Protocol):
    """A sampling motion model: ``sample(poses (N, 3), *u, rng) -> (N, 3)`` (Table 8.2 line 4)."""

    def sample(self, poses: Any, *args: Any) -> NDArray[np.float64]: ...


class SensorModel(Protocol):
    """A measurement model: ``log_likelihood_sum(poses (N, 3), *z) -> (N,)`` (Table 8.2 line 5)."""

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
    max_random_fraction : float
        At most this fraction of the particles is replaced by random ones at a resampling
        (1.0: as Table 8.3 prints it). On real logs the scans fit some places of a map worse
        than others, ``w_fast`` falls well below ``w_slow`` there while the filter tracks, and
        an uncapped fraction replaces most of a good particle set with random poses.
    kld : KLDConfig or None
        Adaptive particle count (Table 8.4) when given.
    cluster_size : float
        Cell size (m) for the best-cluster estimate.
    min_ess_fraction : float or None
        Lower the exponent further where one measurement would leave fewer than this fraction
        of effective particles (:func:`mcl_adaptive_exponent`); None: never.
    independent_measurements : float or None
        Temper the measurement likelihood: a scan of ``B`` beams (landmarks) counts as
        ``min(B, independent_measurements)`` independent ones, i.e. its log-likelihood is
        multiplied by ``min(1, independent_measurements / B)`` (see
        :func:`mcl_likelihood_exponent`). None: every beam independent (Table 8.2 as printed).
    """

    n_particles: int = 1000
    resample_threshold: float = 0.5
    augmented: bool = False
    alpha_slow: float = 0.001
    alpha_fast: float = 0.1
    max_random_fraction: float = 1.0
    kld: KLDConfig | None = None
    cluster_size: float = 0.5
    independent_measurements: float | None = None
    min_ess_fraction: float | None = None

    def __post_init__(self) -> None:
        if self.n_particles <= 0:
            raise ValueError(f"n_particles must be positive, got {self.n_particles}")
        if not 0.0 <= self.resample_threshold <= 1.0:
            raise ValueError(f"resample_threshold must be in [0, 1], got {self.resample_threshold}")
        if not 0.0 <= self.alpha_slow < self.alpha_fast <= 1.0:
            raise ValueError(
                f"need 0 <= alpha_slow < alpha_fast <= 1, got {self.alpha_slow}, {self.alpha_fast}"
            )
        if not 0.0 <= self.max_random_fraction <= 1.0:
            raise ValueError(
                f"max_random_fraction must lie in [0, 1], got {self.max_random_fraction}"
            )
        if not self.cluster_size > 0:
            raise ValueError(f"cluster_size must be positive, got {self.cluster_size}")
        e = self.min_ess_fraction
        if e is not None and not 0 < e < 1:
            raise ValueError(f"min_ess_fraction must lie in (0, 1), got {e}")
        k = self.independent_measurements
        if k is not None and not (math.isfinite(k) and k > 0):
            raise ValueError(f"independent_measurements must be a number > 0, got {k}")


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
        eb = wrap_angle(zz[None, :, 1] - b_hat) / self.sigma_bearing
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


# ---------------------------------------------------------------------------------------------
# Function tier: Table 8.2 (with 8.3 and 8.4) on particle arrays
# ---------------------------------------------------------------------------------------------
def sample_pose_gaussian(
    mean: ArrayLike, covariance: ArrayLike, n: int, rng: np.random.Generator
) -> NDArray[np.float64]:
    """Initial particles for tracking: ``n`` draws from ``N(mean, covariance)``, heading wrapped.

    Parameters
    ----------
    mean : array_like, shape (3,)
        Start pose ``(x, y, theta)``, map frame (m, rad).
    covariance : array_like, shape (3, 3)
        Its covariance (m^2, rad^2); may be singular (eigen-decomposition).
    n : int
        Particle count.
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (n, 3)
    """
    mu = np.asarray(mean, dtype=np.float64)
    cov = np.asarray(covariance, dtype=np.float64)
    if mu.shape != (3,) or cov.shape != (3, 3):
        raise ValueError(f"mean must be (3,) and covariance (3, 3), got {mu.shape}, {cov.shape}")
    p = rng.multivariate_normal(mu, cov, size=n, method="eigh")
    p[:, 2] = wrap_angle(p[:, 2])
    return np.asarray(p)


def mcl_sample_motion(
    particles: NDArray[np.float64],
    motion: MotionModel,
    u: tuple[Any, ...],
    rng: np.random.Generator,
) -> NDArray[np.float64]:
    """Motion sampling, ``x_t^[m] ~ p(x_t | u_t, x_{t-1}^[m])`` (Table 8.2, line 4).

    Parameters
    ----------
    particles : ndarray, shape (N, 3)
        Poses ``(x, y, theta)``, map frame (m, rad).
    motion : MotionModel
        ``sample(poses, *u, rng)``, e.g. :class:`~probmap.models.sampling.OdometryMotionModel`
        (``u = (odom_prev, odom_cur)``) or :class:`~probmap.models.sampling.VelocityMotionModel`
        (``u = ((v, w), dt)``).
    u : tuple
        The control, as the model's ``sample`` takes it.
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (N, 3), C-contiguous
        New poses (the input is not modified).
    """
    return np.ascontiguousarray(motion.sample(particles, *u, rng))


def mcl_weight(
    log_weights: NDArray[np.float64], log_likelihood: NDArray[np.float64]
) -> tuple[NDArray[np.float64], float]:
    """Importance weighting in the log domain, ``w^[m] ~ w^[m] p(z_t | x_t^[m])`` (Table 8.2,
    line 5; the weights carried over when the previous step did not resample), normalised.

    Parameters
    ----------
    log_weights : ndarray, shape (N,)
        Current normalised log weights.
    log_likelihood : ndarray, shape (N,)
        ``log p(z_t | x_t^[m])`` of each particle; NaN counts as impossible.

    Returns
    -------
    log_weights : ndarray, shape (N,)
        Normalised (``logsumexp = 0``); ``-inf`` where impossible.
    ess : float
        Effective sample size ``1 / sum w^2`` of the new weights; ``0.0`` when every particle is
        impossible (the weights are then all ``-inf`` and the caller must recover).
    """
    lw = np.where(np.isnan(log_likelihood), -np.inf, log_weights + log_likelihood)
    top = float(lw.max())
    if not math.isfinite(top):
        return np.full(lw.shape, -np.inf), 0.0
    w = np.exp(lw - top)
    s = float(w.sum())
    with np.errstate(divide="ignore"):
        out = lw - top - math.log(s)
    w /= s
    return out, float(1.0 / np.dot(w, w))


def mcl_likelihood_exponent(count: int, independent: float | None) -> float:
    """The exponent that tempers a measurement of ``count`` beams (landmarks), as if only
    ``independent`` of them were independent: ``min(1, independent / count)``; 1 for None.

    The beams of one scan are not independent (section 6.3.4: the map's errors, people and
    unmodelled objects affect neighbouring beams alike), and counting each as independent
    evidence makes the posterior far too peaked: the particle cloud collapses to a few copies
    of one pose even where the scan cannot fix the pose, along a corridor. Raising
    ``p(z | x)`` to this power (summing ``exponent * log p``) keeps the weights of a scan
    worth ``independent`` beams, whatever the beam count.

    >>> mcl_likelihood_exponent(60, 10.0), mcl_likelihood_exponent(5, 10.0)
    (0.16666666666666666, 1.0)
    """
    if independent is None or count <= independent:
        return 1.0
    return float(independent) / count


def mcl_adaptive_exponent(
    log_weights: NDArray[np.float64],
    log_likelihood: NDArray[np.float64],
    exponent: float,
    min_ess_fraction: float,
) -> float:
    """The largest exponent ``g <= exponent`` whose weights ``w p(z | x)^g`` keep an effective
    sample size of at least ``min_ess_fraction * N`` (found by bisection to ``2**-30`` of
    ``exponent``, in one compiled call; ``exponent`` itself when it already does).

    Adaptive tempering, as sequential Monte Carlo samplers anneal: when one scan would leave a
    handful of effective particles (the first scan of a global localization, where the luckiest
    of thousands of random poses outweighs all others), it is taken in part, so that resampling
    keeps every place that fits and the next scans decide between them.

    >>> import numpy as np
    >>> lw = np.full(4, -np.log(4)); ll = np.array([0.0, -100.0, -100.0, -100.0])
    >>> g = mcl_adaptive_exponent(lw, ll, 1.0, 0.5)
    >>> 0.0 < g < 0.05, mcl_adaptive_exponent(lw, np.zeros(4), 1.0, 0.5)
    (True, 1.0)
    """
    return float(
        _k.adaptive_exponent(
            np.ascontiguousarray(log_weights, dtype=np.float64),
            np.ascontiguousarray(log_likelihood, dtype=np.float64),
            float(exponent),
            float(min_ess_fraction),
        )
    )


def mcl_likelihood_averages(
    w_slow: float,
    w_fast: float,
    log_likelihood: NDArray[np.float64],
    count: int,
    alpha_slow: float,
    alpha_fast: float,
) -> tuple[float, float]:
    """Long- and short-term average likelihoods of augmented MCL (Table 8.3, lines 6-10).

    ``w_avg`` is the mean particle likelihood taken per measurement (geometric mean over the
    ``count`` beams or landmarks), so it stays in floating-point range whatever ``count``;
    ``w_slow += alpha_slow (w_avg - w_slow)``, ``w_fast += alpha_fast (w_avg - w_fast)``, both
    started at the first ``w_avg`` (when ``w_slow == 0``).

    Parameters
    ----------
    w_slow, w_fast : float
        Current averages (0 before the first measurement).
    log_likelihood : ndarray, shape (N,)
        ``log p(z_t | x_t^[m])`` (all measurements of the step).
    count : int
        Number of measurements in ``z_t``.
    alpha_slow, alpha_fast : float
        Decay rates, ``0 <= alpha_slow << alpha_fast``.

    Returns
    -------
    w_slow, w_fast : float
    """
    ll = log_likelihood
    log_avg = (float(np.log(np.exp(ll - ll.max()).mean())) + float(ll.max())) / max(count, 1)
    w_avg = math.exp(min(log_avg, 700.0))
    if w_slow == 0.0:
        w_slow = w_fast = w_avg
    w_slow += alpha_slow * (w_avg - w_slow)
    w_fast += alpha_fast * (w_avg - w_fast)
    return w_slow, w_fast


def mcl_random_fraction(w_slow: float, w_fast: float) -> float:
    """Probability of a random particle, ``max(0, 1 - w_fast / w_slow)`` (Table 8.3 line 12);
    0 before the first measurement (``w_slow <= 0``)."""
    if w_slow <= 0.0:
        return 0.0
    return max(0.0, 1.0 - w_fast / w_slow)


def mcl_resample(
    particles: NDArray[np.float64],
    weights: NDArray[np.float64],
    rng: np.random.Generator,
    kld: KLDConfig | None = None,
    random_fraction: float = 0.0,
    free_space: FreeSpaceSampler | None = None,
    count_rng: np.random.Generator | None = None,
) -> NDArray[np.float64]:
    """Resampling (Table 8.2, lines 8-11).

    Low-variance resampling (Table 4.4, one uniform draw) of ``N`` particles, or of as many as
    KLD-sampling (Table 8.4, :func:`~probmap.filters.kld.kld_count`) asks for when ``kld`` is
    given (the low-variance draw covers the bins at least as well as Table 8.4's independent
    draws, which set the count); then, under augmented MCL, each new particle is replaced with
    probability ``random_fraction`` by a pose uniform over free space (Table 8.3, lines 11-15:
    a binomial count of slots chosen without replacement).

    Parameters
    ----------
    particles : ndarray, shape (N, 3)
        Poses, map frame (m, rad).
    weights : ndarray, shape (N,)
        Normalised weights.
    rng : numpy.random.Generator
    kld : KLDConfig, optional
    random_fraction : float
        From :func:`mcl_random_fraction`; used only with ``free_space``.
    free_space : FreeSpaceSampler, optional
    count_rng : numpy.random.Generator, optional
        For KLD-sampling's counting draws (default ``rng``): a generator of their own leaves
        the filter's random stream as it is without KLD-sampling wherever the count is ``N``.

    Returns
    -------
    ndarray, shape (M, 3)
        ``M = N`` unless KLD-sampling chose another count. Weights are uniform afterwards.
    """
    src = np.ascontiguousarray(particles, dtype=np.float64)
    m = src.shape[0] if kld is None else kld_count(src, weights, count_rng or rng, kld)
    idx = np.empty(m, dtype=np.int64)
    _k.low_variance_indexes(weights, float(rng.uniform()), idx)
    new = np.empty((idx.shape[0], 3))
    _k.gather_rows(src, idx, new)
    if random_fraction > 0.0 and free_space is not None:
        k = int(rng.binomial(new.shape[0], random_fraction))
        if k:
            slots = rng.choice(new.shape[0], size=k, replace=False)
            new[slots] = free_space.sample(k, rng)
    return new


# MonteCarloLocalization.predict_and_weight is the class tier over this function: same inputs.
def mcl_sample_and_weight_scan(
    particles: NDArray[np.float64],
    odom_prev: ArrayLike,
    odom_cur: ArrayLike,
    lx: NDArray[np.float64],
    ly: NDArray[np.float64],
    field: LikelihoodField,
    motion: OdometryMotionModel,
    rng: np.random.Generator,
) -> NDArray[np.float64]:
    """Table 8.2 lines 4-5 fused for odometry (Table 5.6) and a likelihood field (Table 6.3).

    One compiled pass moves each particle by a noisy sample of the odometry step and sums the
    log-likelihood of the scan endpoints seen from it.

    Parameters
    ----------
    particles : ndarray, shape (N, 3), C-contiguous float64
        Poses, map frame (m, rad); **moved in place**.
    odom_prev, odom_cur : array_like, shape (3,)
        Odometry poses before and after the step (odometry frame).
    lx, ly : ndarray, shape (B,)
        Valid scan endpoints in the robot frame (m), e.g. from ``field.endpoints``.
    field : LikelihoodField
    motion : OdometryMotionModel
    rng : numpy.random.Generator
        Source of the ``(N, 3)`` standard-normal noise.

    Returns
    -------
    ndarray, shape (N,)
        Log-likelihood of the scan for each moved particle.
    """
    r1, tr, r2 = (float(v) for v in odometry_deltas(odom_prev, odom_cur))
    sd1, sdt, sd2 = odometry_noise_std(r1, tr, r2, motion.alphas, motion.unit_step)
    n = particles.shape[0]
    noise = rng.standard_normal((n, 3))
    ll = np.zeros(n)
    f = field.frame
    _k.odometry_predict_and_weight(
        particles,
        noise,
        r1,
        tr,
        r2,
        sd1,
        sdt,
        sd2,
        np.ascontiguousarray(lx),
        np.ascontiguousarray(ly),
        field.table,
        f.x0,
        f.y0,
        1.0 / f.resolution,
        field.outside,
        ll,
    )
    return ll


class MonteCarloLocalization:
    """Monte Carlo localization, Tables 8.2-8.4.

    A thin class over the function tier (:func:`mcl_sample_motion`, :func:`mcl_weight`,
    :func:`mcl_resample`, ...): it holds the particle set, the log weights, the random
    generator and the augmented-MCL averages.

    Parameters
    ----------
    sensor : SensorModel
        Measurement model with ``log_likelihood_sum(poses, *z)``.
    motion : MotionModel
        Motion model with ``sample(poses, *u, rng)``.
    rng : numpy.random.Generator
    config : MCLConfig, optional
    free_space : FreeSpaceSampler, optional
        Needed for global localization, augmented MCL and recovery from all-zero weights.
    particles : array_like, shape (N, 3), keyword-only
        The initial particle set ``(x, y, theta)``, map frame (m, rad), with uniform weights;
        see also :meth:`from_pose` and :meth:`uniform`.

    Examples
    --------
    >>> import numpy as np
    >>> from probmap.models.sampling import VelocityMotionModel
    >>> lm = RangeBearingLandmarks(np.array([1]), np.array([[2.0, 0.0]]))
    >>> mcl = MonteCarloLocalization.from_pose(
    ...     lm, VelocityMotionModel(), np.random.default_rng(0), [0.0, 0.0, 0.0],
    ...     np.diag([0.01, 0.01, 0.01]), MCLConfig(n_particles=100))
    >>> mcl.n, mcl.particles.shape
    (100, (100, 3))
    """

    def __init__(
        self,
        sensor: SensorModel,
        motion: MotionModel,
        rng: np.random.Generator,
        config: MCLConfig | None = None,
        free_space: FreeSpaceSampler | None = None,
        *,
        particles: ArrayLike,
    ) -> None:
        self.config = config or MCLConfig()
        if self.config.augmented and free_space is None:
            raise ValueError("augmented MCL needs a free_space sampler for random particles")
        self.sensor = sensor
        self.motion = motion
        self.rng = rng
        self._count_rng: np.random.Generator | None = None  # KLD's counting draws, lazily
        self.free_space = free_space
        #: Whether resampling injects random particles now (Table 8.3); ``config.augmented`` at
        #: first. A caller may switch it: the localization pipeline turns it on only while its
        #: filter is lost, since on real logs the scans fit some places of a map worse than
        #: others and ``w_fast`` falls below ``w_slow`` there while the filter tracks well.
        self.augment = self.config.augmented
        #: While ``augment`` is on, at least this fraction of random particles (a caller that
        #: knows the filter is lost need not wait for ``w_fast`` to fall below ``w_slow``).
        self.random_floor = 0.0
        self.w_slow = 0.0
        self.w_fast = 0.0
        self.last_exponent = 1.0  # the exponent the last measurement was taken to
        #: update_scan's robust pass (:func:`probmap.filters.mcl_robust.mcl_sample_and_weight_robust`):
        #: a wall margin (m; None: off) and the fraction of particles moved by the odometry reversed.
        self.wall_margin: float | None = None
        self.reverse_fraction = 0.0
        p = np.array(particles, dtype=np.float64)  # a copy: the filter moves it in place
        if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] == 0:
            raise ValueError(f"particles must have shape (N, 3) with N > 0, got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise ValueError("particles must be finite")
        self._reset(p)

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def from_pose(
        cls,
        sensor: SensorModel,
        motion: MotionModel,
        rng: np.random.Generator,
        mean: ArrayLike,
        covariance: ArrayLike,
        config: MCLConfig | None = None,
        free_space: FreeSpaceSampler | None = None,
    ) -> MonteCarloLocalization:
        """Tracking: ``config.n_particles`` particles from ``N(mean, covariance)``
        (:func:`sample_pose_gaussian`, drawn from ``rng``).

        ``mean`` is ``(x, y, theta)`` (3,) in the map frame (m, rad), ``covariance`` (3, 3).
        """
        cfg = config or MCLConfig()
        p = sample_pose_gaussian(mean, covariance, cfg.n_particles, rng)
        return cls(sensor, motion, rng, cfg, free_space, particles=p)

    @classmethod
    def uniform(
        cls,
        sensor: SensorModel,
        motion: MotionModel,
        rng: np.random.Generator,
        free_space: FreeSpaceSampler,
        config: MCLConfig | None = None,
    ) -> MonteCarloLocalization:
        """Global localization: ``config.n_particles`` particles uniform over ``free_space``."""
        cfg = config or MCLConfig()
        p = free_space.sample(cfg.n_particles, rng)
        return cls(sensor, motion, rng, cfg, free_space, particles=p)

    def restart(self) -> None:
        """Global localization again: ``config.n_particles`` particles uniform over
        ``free_space`` (ValueError without one), uniform weights, augmented MCL's averages
        cleared."""
        if self.free_space is None:
            raise ValueError("restart needs a free_space sampler")
        self._reset(self.free_space.sample(self.config.n_particles, self.rng))
        self.w_slow = self.w_fast = 0.0

    def resize(self, n: int) -> None:
        """Resample the weighted set to exactly ``n`` particles (low-variance, Table 4.4;
        uniform weights afterwards): a filter that KLD-sampling shrank, made to search again."""
        if n < 1:
            raise ValueError(f"n must be at least 1, got {n}")
        idx = np.empty(int(n), dtype=np.int64)
        _k.low_variance_indexes(self.weights, float(self.rng.uniform()), idx)
        new = np.empty((idx.shape[0], 3))
        _k.gather_rows(np.ascontiguousarray(self.particles), idx, new)
        self._reset(new)

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
        self.particles = mcl_sample_motion(self.particles, self.motion, u, self.rng)

    def correct(self, *z: Any) -> None:
        """Weight every particle by the measurement model (Table 8.2, line 5)."""
        ll = np.asarray(self.sensor.log_likelihood_sum(self.particles, *z), dtype=np.float64)
        if ll.shape != (self.n,):
            raise ValueError(f"sensor returned shape {ll.shape}, expected ({self.n},)")
        self._add_log_likelihood(ll, _measurement_count(z))

    def _add_log_likelihood(self, ll: NDArray[np.float64], count: int) -> None:
        gamma = mcl_likelihood_exponent(count, self.config.independent_measurements)
        if self.config.min_ess_fraction is not None:
            gamma = mcl_adaptive_exponent(self.log_weights, ll, gamma, self.config.min_ess_fraction)
        self.last_exponent = gamma
        lw, ess = mcl_weight(self.log_weights, ll if gamma == 1.0 else gamma * ll)
        if ess == 0.0:  # every particle impossible
            self._recover()
            return
        # kept with or without augmented MCL: w_fast / w_slow tells how well the scans fit
        cfg = self.config
        self.w_slow, self.w_fast = mcl_likelihood_averages(
            self.w_slow, self.w_fast, ll, count, cfg.alpha_slow, cfg.alpha_fast
        )
        self.log_weights = lw
        self.last_ess = ess

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
        if not self.augment or self.free_space is None:
            return 0.0
        frac = min(mcl_random_fraction(self.w_slow, self.w_fast), self.config.max_random_fraction)
        return max(frac, self.random_floor)

    def resample(self) -> None:
        """Low-variance resampling (Table 4.4), KLD-sampling when configured (Table 8.4),
        with random particles injected under augmented MCL (Table 8.3)."""
        if self.config.kld is not None and self._count_rng is None:
            self._count_rng = self.rng.spawn(1)[0]  # the parent's stream is not advanced
        new = mcl_resample(
            self.particles,
            self.weights,
            self.rng,
            self.config.kld,
            self.random_fraction(),
            self.free_space,
            self._count_rng,
        )
        self._reset(new)

    # ParticleFilter.resample_if_needed's ESS rule, plus augmented MCL's random particles and
    # the KLD resampler (Tables 8.3, 8.4): MCL keeps its own particle set and weights.
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

        When the odometry has not moved (``odom_prev == odom_cur``) nothing happens: no
        measurement update and no resampling. A scan taken again from the same place is not
        independent evidence, and resampling without motion noise only removes particles until
        all are copies of one (particle deprivation, Probabilistic Robotics section 8.3.5).
        """
        if np.array_equal(np.asarray(odom_prev, float), np.asarray(odom_cur, float)):
            return self.estimate()
        if not (
            isinstance(self.sensor, LikelihoodField)
            and isinstance(self.motion, OdometryMotionModel)
        ):
            return self.update((odom_prev, odom_cur), (ranges, angles, sensor_offset))
        lf, mm = self.sensor, self.motion
        lx, ly, valid = lf.endpoints(ranges, angles, sensor_offset)
        if self.wall_margin is None and not self.reverse_fraction > 0:
            self.predict_and_weight(odom_prev, odom_cur, lx[valid], ly[valid], lf, mm)
        else:
            ll = _robust(self, odom_prev, odom_cur, lx[valid], ly[valid], sensor_offset)
            self._add_log_likelihood(ll, int(valid.sum()))
        est = self.estimate()
        self.resample_if_needed()
        return est

    # the class tier over mcl_sample_and_weight_scan: its inputs, less the filter's own state
    def predict_and_weight(
        self,
        odom_prev: ArrayLike,
        odom_cur: ArrayLike,
        lx: NDArray[np.float64],
        ly: NDArray[np.float64],
        lf: LikelihoodField,
        mm: OdometryMotionModel,
    ) -> None:
        """Fused odometry sampling + likelihood-field weighting for valid endpoints ``lx, ly``
        (:func:`mcl_sample_and_weight_scan`)."""
        ll = mcl_sample_and_weight_scan(
            self.particles, odom_prev, odom_cur, lx, ly, lf, mm, self.rng
        )
        self._add_log_likelihood(ll, int(lx.shape[0]))

    # -- estimates ----------------------------------------------------------------------------
    def hypotheses(self, min_weight: float = 0.05) -> list[Hypothesis]:
        """The particle set's clusters (:func:`particle_clusters`, cells of
        ``config.cluster_size``), heaviest first."""
        return particle_clusters(self.particles, self.weights, self.config.cluster_size, min_weight)

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
