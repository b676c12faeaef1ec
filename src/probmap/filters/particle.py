"""A general particle filter over arrays of states (Probabilistic Robotics Table 4.3).

Two tiers: array functions (weighted pose statistics) and :class:`ParticleFilter`, a thin
stateful class holding particles ``(N, D)`` and log weights ``(N,)``. Weights live in the
log domain and are normalised with log-sum-exp; resampling happens only when the effective
sample size drops below ``resample_threshold * N`` (Section 4.3.4).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap.errors import ParticleFilterWarning
from probmap.filters.resampling import Resampler, log_normalize, low_variance_resample
from probmap.geometry.se2 import wrap_angle

__all__ = [
    "ParticleFilter",
    "ParticleFilterWarning",
    "circular_mean",
    "weighted_pose_covariance",
    "weighted_pose_mean",
]


def circular_mean(angles: ArrayLike, weights: ArrayLike) -> float:
    """Weighted circular mean ``atan2(sum w sin a, sum w cos a)`` of angles (rad)."""
    a = np.asarray(angles, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    # multiply-and-sum rather than np.dot: BLAS dot on strided columns starts threads whose
    # overhead dwarfs the arithmetic for particle-sized vectors
    return float(np.arctan2((w * np.sin(a)).sum(), (w * np.cos(a)).sum()))


def weighted_pose_mean(poses: ArrayLike, weights: ArrayLike) -> NDArray[np.float64]:
    """Weighted mean of SE(2) poses ``(N, 3)``: arithmetic in x, y, circular in theta.

    Parameters
    ----------
    poses : (N, 3) array_like
        (x, y, theta) in m and rad.
    weights : (N,) array_like
        Normalised weights.

    Returns
    -------
    (3,) ndarray
    """
    p = np.asarray(poses, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    return np.array([(w * p[:, 0]).sum(), (w * p[:, 1]).sum(), circular_mean(p[:, 2], w)])


def weighted_pose_covariance(
    poses: ArrayLike, weights: ArrayLike, mean: ArrayLike | None = None
) -> NDArray[np.float64]:
    """Weighted covariance ``(3, 3)`` of poses, heading residuals wrapped to ``[-pi, pi)``."""
    p = np.asarray(poses, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    mu = weighted_pose_mean(p, w) if mean is None else np.asarray(mean, dtype=np.float64)
    d = p - mu
    d[:, 2] = wrap_angle(d[:, 2])
    return np.asarray((d * w[:, None]).T @ d)


class ParticleFilter:
    """Particle filter with log-domain weights and adaptive resampling.

    Parameters
    ----------
    particles : (N, D) array_like
        Initial state samples.
    motion : callable ``(particles (N, D), *control, rng=Generator) -> (N, D)``
        Draws ``x_t ~ p(x_t | u_t, x_{t-1})`` for every particle.
    log_likelihood : callable ``(particles (N, D), *measurement) -> (N,)``
        ``log p(z_t | x_t)`` per particle; ``-inf`` marks an impossible particle.
    rng : numpy.random.Generator
        Randomness for the motion model and resampling.
    resample_threshold : float
        Resample when ESS < ``resample_threshold * N`` (1.0 resamples every step).
    resampler : callable
        Weights -> indexes (see :mod:`probmap.filters.resampling`).
    """

    def __init__(
        self,
        particles: ArrayLike,
        motion: Callable[..., NDArray[np.float64]],
        log_likelihood: Callable[..., NDArray[np.float64]],
        rng: np.random.Generator,
        *,
        resample_threshold: float = 0.5,
        resampler: Resampler = low_variance_resample,
    ) -> None:
        x = np.array(particles, dtype=np.float64)
        if x.ndim == 1:
            x = x[:, None]
        if x.ndim != 2 or x.shape[0] == 0:
            raise ValueError(f"particles must be a non-empty (N, D) array, got {np.shape(x)}")
        if not 0.0 <= resample_threshold <= 1.0:
            raise ValueError(f"resample_threshold must be in [0, 1], got {resample_threshold}")
        self.particles = x
        self.log_weights = np.full(x.shape[0], -np.log(x.shape[0]))
        self.motion = motion
        self.log_likelihood = log_likelihood
        self.rng = rng
        self.resample_threshold = float(resample_threshold)
        self.resampler = resampler
        self.last_log_evidence = 0.0

    @property
    def n(self) -> int:
        return int(self.particles.shape[0])

    @property
    def weights(self) -> NDArray[np.float64]:
        """Normalised weights ``(N,)``."""
        return log_normalize(self.log_weights)[0]

    @property
    def ess(self) -> float:
        """Effective sample size ``1 / sum(w^2)``."""
        w = self.weights
        return float(1.0 / np.dot(w, w))

    def predict(self, *control: Any) -> None:
        """Sample every particle through the motion model (Table 4.3, line 4)."""
        x = np.asarray(self.motion(self.particles, *control, rng=self.rng), dtype=np.float64)
        if x.shape[0] != self.n:
            raise ValueError(f"motion model returned {x.shape[0]} particles, expected {self.n}")
        self.particles = x.reshape(self.n, -1)

    def correct(self, *measurement: Any) -> None:
        """Multiply in the measurement likelihood (Table 4.3, line 5) and normalise.

        When every particle is impossible the weights are reset to uniform (the measurement
        is ignored) with a :class:`ParticleFilterWarning`, instead of producing NaN.
        """
        ll = np.asarray(self.log_likelihood(self.particles, *measurement), dtype=np.float64)
        if ll.shape != (self.n,):
            raise ValueError(f"log_likelihood returned shape {ll.shape}, expected ({self.n},)")
        w, total = log_normalize(self.log_weights + ll)
        if not np.isfinite(total):
            warnings.warn(
                "every particle has zero likelihood; measurement ignored, weights reset",
                ParticleFilterWarning,
                stacklevel=2,
            )
            self.log_weights = np.full(self.n, -np.log(self.n))
            self.last_log_evidence = -np.inf
            return
        self.last_log_evidence = total
        with np.errstate(divide="ignore"):
            self.log_weights = np.log(w)

    def resample(self) -> None:
        """Draw with replacement by weight (Table 4.3, lines 8-11); weights become uniform."""
        idx = self.resampler(self.weights, self.rng)
        self.particles = self.particles[idx]
        self.log_weights = np.full(self.n, -np.log(self.n))

    # MonteCarloLocalization has its own (the same ESS rule, plus augmented MCL's random
    # particles and KLD sampling): the generic filter stays the plain Table 4.3.
    def resample_if_needed(self) -> bool:
        """Resample when the effective sample size is below the threshold; return whether."""
        if self.ess < self.resample_threshold * self.n:
            self.resample()
            return True
        return False

    def step(self, control: tuple[Any, ...], measurement: tuple[Any, ...]) -> None:
        """Predict, correct, and resample if needed."""
        self.predict(*control)
        self.correct(*measurement)
        self.resample_if_needed()

    def mean(self) -> NDArray[np.float64]:
        """Weighted mean of the state ``(D,)`` (plain arithmetic mean)."""
        return np.asarray(self.weights @ self.particles)

    def covariance(self) -> NDArray[np.float64]:
        """Weighted covariance ``(D, D)``."""
        w = self.weights
        d = self.particles - w @ self.particles
        return np.asarray((d * w[:, None]).T @ d)
