"""KLD-sampling: an adaptive particle count (Probabilistic Robotics Table 8.4, Fox 2003).

Particles are drawn one batch at a time; each drawn pose is put into a histogram bin, and
drawing stops once the count exceeds the bound (Table 8.4, line 14) for the number of
non-empty bins ``k``:

    n = (k - 1) / (2 eps) * (1 - 2 / (9 (k - 1)) + sqrt(2 / (9 (k - 1))) z_{1-delta})^3

so that with probability ``1 - delta`` the KL divergence between the sample-based and the
true (binned) posterior stays below ``eps``. Bins are taken on the resampled poses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap.filters._kernels import pose_bounds as _pose_bounds

__all__ = ["KLDConfig", "kld_count", "kld_resample", "kld_sample_size"]


@dataclass(frozen=True)
class KLDConfig:
    """KLD-sampling parameters.

    Parameters
    ----------
    epsilon : float
        Bound on the KL divergence.
    delta : float
        The bound holds with probability ``1 - delta``.
    bin_size : (float, float, float)
        Histogram bin (m, m, rad).
    n_min, n_max : int
        Particle count limits.
    """

    epsilon: float = 0.05
    delta: float = 0.01
    bin_size: tuple[float, float, float] = (0.5, 0.5, math.radians(10.0))
    n_min: int = 100
    n_max: int = 20000

    def __post_init__(self) -> None:
        if not (self.epsilon > 0 and 0 < self.delta < 1):
            raise ValueError(
                f"need epsilon > 0 and 0 < delta < 1, got {self.epsilon}, {self.delta}"
            )
        if any(not b > 0 for b in self.bin_size):
            raise ValueError(f"bin sizes must be positive, got {self.bin_size}")
        if not 0 < self.n_min <= self.n_max:
            raise ValueError(f"need 0 < n_min <= n_max, got {self.n_min}, {self.n_max}")


def kld_sample_size(k: int, epsilon: float, delta: float) -> int:
    """Particles needed for ``k`` non-empty bins, Table 8.4 line 14 (Wilson-Hilferty).

    Returns 1 for ``k <= 1``.

    >>> kld_sample_size(1, 0.05, 0.01), kld_sample_size(2, 0.05, 0.01)
    (1, 66)
    """
    return int(_sample_sizes(np.array([k], dtype=np.int64), epsilon, delta)[0])


def _sample_sizes(k: NDArray[np.int64], epsilon: float, delta: float) -> NDArray[np.int64]:
    """:func:`kld_sample_size` for an array of bin counts (1 where ``k <= 1``)."""
    z = NormalDist().inv_cdf(1.0 - delta)
    km1 = np.maximum(k - 1, 1).astype(np.float64)
    a = 2.0 / (9.0 * km1)
    n = np.ceil(km1 / (2.0 * epsilon) * (1.0 - a + np.sqrt(a) * z) ** 3).astype(np.int64)
    return np.where(k <= 1, 1, n)


def _bin_keys(p: NDArray[np.float64], config: KLDConfig) -> NDArray[np.int64]:
    """One integer per pose for its ``(x, y, theta)`` histogram bin."""
    b = np.floor(p / np.asarray(config.bin_size)).astype(np.int64)
    b -= b.min(axis=0)
    span = b.max(axis=0) + 1
    return np.asarray((b[:, 0] * span[1] + b[:, 1]) * span[2] + b[:, 2])


def _checked(
    poses: ArrayLike, weights: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    p = np.asarray(poses, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or w.shape != (p.shape[0],):
        raise ValueError(f"poses must be (N, 3) and weights (N,), got {p.shape}, {w.shape}")
    return p, w


def kld_resample(
    poses: ArrayLike, weights: ArrayLike, rng: np.random.Generator, config: KLDConfig
) -> NDArray[np.int64]:
    """Draw indexes by weight until the KLD bound for the bins hit so far is met.

    Table 8.4 draws one particle at a time and stops at the first draw ``M`` for which
    ``M >= max(n_min, kld_sample_size(k_M))``, ``k_M`` being the bins hit by the first ``M``
    draws (at ``n_max`` at the latest). Here the draws come in batches and the stopping
    point is found for a whole batch at once; it is the same ``M`` the one-at-a-time loop
    gives for the same draws.

    Parameters
    ----------
    poses : (N, 3) array_like
        Weighted particle poses (m, m, rad).
    weights : (N,) array_like
        Normalised weights.
    rng : numpy.random.Generator
    config : KLDConfig

    Returns
    -------
    (M,) int64 ndarray
        ``n_min <= M <= n_max`` indexes, sorted.
    """
    p, w = _checked(poses, weights)
    return np.sort(_draw_until_bound(_bin_keys(p, config), w, rng, config))


def kld_count(
    poses: ArrayLike, weights: ArrayLike, rng: np.random.Generator, config: KLDConfig
) -> int:
    """The particle count KLD-sampling (Table 8.4) stops at, for a resampler that draws the
    particles another way (low-variance resampling, Table 4.4).

    Where the bound for every bin the weighted set occupies (or its bounding box spans) is at
    most ``n_min``, no draw can ask for more: ``n_min``, without drawing (``rng`` untouched;
    a tight cloud tracking). Otherwise the draws of :func:`kld_resample`, counted and not
    kept.

    Parameters
    ----------
    poses : (N, 3) array_like
        Weighted particle poses (m, m, rad).
    weights : (N,) array_like
        Normalised weights.
    rng : numpy.random.Generator
    config : KLDConfig

    Returns
    -------
    int
        ``n_min <= M <= n_max``.
    """
    p, w = _checked(poses, weights)
    # the bins of the cloud's bounding box bound the bins it occupies: a tight cloud is done
    bounds = np.empty((2, 3))
    _pose_bounds(np.ascontiguousarray(p), bounds)
    lo, hi = (np.floor(b / np.asarray(config.bin_size)) for b in bounds)
    if kld_sample_size(int(np.prod(hi - lo + 1)), config.epsilon, config.delta) <= config.n_min:
        return config.n_min
    keys = _bin_keys(p, config)
    occupied = np.unique(keys[w > 0]).size
    if kld_sample_size(occupied, config.epsilon, config.delta) <= config.n_min:
        return config.n_min
    return int(_draw_until_bound(keys, w, rng, config).size)


def _draw_until_bound(
    keys: NDArray[np.int64], w: NDArray[np.float64], rng: np.random.Generator, config: KLDConfig
) -> NDArray[np.int64]:
    """Table 8.4's draws (indexes into ``w``) up to where the bound is met, in draw order."""
    cum = np.cumsum(w / w.sum())
    drawn = np.empty(0, dtype=np.int64)
    batch = max(config.n_min, min(w.size, config.n_max), 256)  # this set's size: a good guess
    while True:
        size = min(batch, config.n_max - drawn.size)
        new = np.searchsorted(cum, rng.uniform(size=size), side="right")
        drawn = np.concatenate([drawn, np.minimum(new, w.size - 1)])
        # bins hit by the first m + 1 draws, for every m
        _, first = np.unique(keys[drawn], return_index=True)
        fresh = np.zeros(drawn.size, dtype=np.int64)
        fresh[first] = 1
        need = np.maximum(
            _sample_sizes(np.cumsum(fresh), config.epsilon, config.delta), config.n_min
        )
        met = np.arange(1, drawn.size + 1) >= np.minimum(need, config.n_max)
        if met.any():
            return drawn[: int(np.argmax(met)) + 1]
        batch *= 2
