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

__all__ = ["KLDConfig", "kld_resample", "kld_sample_size"]


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
    if k <= 1:
        return 1
    z = NormalDist().inv_cdf(1.0 - delta)
    a = 2.0 / (9.0 * (k - 1))
    return int(math.ceil((k - 1) / (2.0 * epsilon) * (1.0 - a + math.sqrt(a) * z) ** 3))


def kld_resample(
    poses: ArrayLike, weights: ArrayLike, rng: np.random.Generator, config: KLDConfig
) -> NDArray[np.int64]:
    """Draw indexes by weight until the KLD bound for the bins hit so far is met.

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
        ``n_min <= M <= n_max`` indexes.
    """
    p = np.asarray(poses, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or w.shape != (p.shape[0],):
        raise ValueError(f"poses must be (N, 3) and weights (N,), got {p.shape}, {w.shape}")
    cum = np.cumsum(w / w.sum())
    bins = np.floor(p / np.asarray(config.bin_size)).astype(np.int64)
    seen: set[tuple[int, int, int]] = set()
    drawn: list[NDArray[np.int64]] = []
    total = 0
    batch = max(16, config.n_min // 4)
    while True:
        idx = np.minimum(np.searchsorted(cum, rng.uniform(size=batch), side="right"), w.size - 1)
        # Add draws one at a time so the stopping point is exactly where the bound is met.
        for j, i in enumerate(idx):
            seen.add((int(bins[i, 0]), int(bins[i, 1]), int(bins[i, 2])))
            total += 1
            need = max(config.n_min, kld_sample_size(len(seen), config.epsilon, config.delta))
            if total >= min(need, config.n_max):
                drawn.append(idx[: j + 1].astype(np.int64))
                return np.sort(np.concatenate(drawn))
        drawn.append(idx.astype(np.int64))
