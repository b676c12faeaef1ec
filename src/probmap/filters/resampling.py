"""Resampling for particle filters: pure functions from weights to particle indexes.

Every function takes normalised or unnormalised non-negative weights of shape ``(N,)`` and
returns ``(M,)`` int64 indexes into the particle set (``M = N`` unless ``n`` is given). Each
scheme is unbiased: the expected number of copies of particle ``i`` is ``M * w_i``. They
differ in variance: multinomial is the noisiest, then stratified and residual, and the
low-variance (systematic) sampler of Probabilistic Robotics Table 4.4 the least noisy.

Also here: log-domain normalisation (log-sum-exp) and the effective sample size.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

Resampler = Callable[[NDArray[np.float64], np.random.Generator], NDArray[np.int64]]

__all__ = [
    "Resampler",
    "effective_sample_size",
    "log_normalize",
    "low_variance_resample",
    "multinomial_resample",
    "residual_resample",
    "stratified_resample",
    "systematic_resample",
]


def _check_weights(weights: ArrayLike) -> NDArray[np.float64]:
    """Validate weights once and return them normalised to sum 1."""
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 1 or w.size == 0:
        raise ValueError(f"weights must be a non-empty 1-D array, got shape {w.shape}")
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite and non-negative")
    total = float(w.sum())
    if total <= 0.0:
        raise ValueError("weights sum to zero: every particle is impossible")
    return w / total


def _count(n: int | None, w: NDArray[np.float64]) -> int:
    m = w.size if n is None else int(n)
    if m <= 0:
        raise ValueError(f"number of particles to draw must be positive, got {m}")
    return m


def _search(cumulative: NDArray[np.float64], u: NDArray[np.float64]) -> NDArray[np.int64]:
    # side="right": u exactly at a boundary goes to the next particle, and clipping guards
    # against the last cumulative sum landing a hair under 1.0 through rounding.
    idx = np.searchsorted(cumulative, u, side="right")
    return np.minimum(idx, cumulative.size - 1).astype(np.int64)


def low_variance_resample(
    weights: ArrayLike, rng: np.random.Generator, n: int | None = None
) -> NDArray[np.int64]:
    """Low-variance (systematic) resampling, Probabilistic Robotics Table 4.4.

    One random offset ``r ~ U(0, 1/M)``; the ``m``-th draw picks the particle whose
    cumulative-weight interval contains ``r + m/M``.

    Parameters
    ----------
    weights : (N,) array_like
        Non-negative importance weights (normalised here).
    rng : numpy.random.Generator
        Source of the single uniform draw.
    n : int, optional
        Number of indexes to draw (default ``N``).

    Returns
    -------
    (M,) int64 ndarray
        Indexes into the particle set, sorted ascending.

    Examples
    --------
    Each particle gets ``floor(N w)`` or ``ceil(N w)`` copies:

    >>> idx = low_variance_resample([0.5, 0.25, 0.25, 0.0], np.random.default_rng(0))
    >>> np.bincount(idx, minlength=4).tolist()
    [2, 1, 1, 0]
    """
    w = _check_weights(weights)
    m = _count(n, w)
    u = (rng.uniform(0.0, 1.0) + np.arange(m)) / m
    return _search(np.cumsum(w), u)


systematic_resample = low_variance_resample


def stratified_resample(
    weights: ArrayLike, rng: np.random.Generator, n: int | None = None
) -> NDArray[np.int64]:
    """Stratified resampling: one independent uniform draw in each stratum ``[m/M, (m+1)/M)``.

    Parameters and returns as :func:`low_variance_resample`.
    """
    w = _check_weights(weights)
    m = _count(n, w)
    u = (rng.uniform(0.0, 1.0, size=m) + np.arange(m)) / m
    return _search(np.cumsum(w), u)


def multinomial_resample(
    weights: ArrayLike, rng: np.random.Generator, n: int | None = None
) -> NDArray[np.int64]:
    """Multinomial resampling: ``M`` independent draws from the categorical distribution.

    Parameters and returns as :func:`low_variance_resample` (indexes sorted ascending).
    """
    w = _check_weights(weights)
    m = _count(n, w)
    u = np.sort(rng.uniform(0.0, 1.0, size=m))
    return _search(np.cumsum(w), u)


def residual_resample(
    weights: ArrayLike, rng: np.random.Generator, n: int | None = None
) -> NDArray[np.int64]:
    """Residual resampling: ``floor(M w_i)`` deterministic copies, the rest multinomial.

    The remaining ``M - sum(floor(M w_i))`` draws come from the residual weights
    ``M w_i - floor(M w_i)`` (normalised), so the expected count is still ``M w_i``.

    Parameters and returns as :func:`low_variance_resample` (indexes sorted ascending).
    """
    w = _check_weights(weights)
    m = _count(n, w)
    scaled = m * w
    copies = np.floor(scaled).astype(np.int64)
    idx = np.repeat(np.arange(w.size, dtype=np.int64), copies)
    rest = m - int(copies.sum())
    if rest > 0:
        residual = scaled - copies
        u = np.sort(rng.uniform(0.0, 1.0, size=rest))
        extra = _search(np.cumsum(residual / residual.sum()), u)
        idx = np.sort(np.concatenate([idx, extra]))
    return idx


def log_normalize(log_weights: ArrayLike) -> tuple[NDArray[np.float64], float]:
    """Normalise log weights with log-sum-exp.

    Parameters
    ----------
    log_weights : (N,) array_like
        Unnormalised log weights; ``-inf`` marks an impossible particle.

    Returns
    -------
    weights : (N,) ndarray
        ``exp(l_i - logsumexp(l))``, summing to 1. When every entry is ``-inf`` (or NaN)
        the weights are NaN-free zeros and ``log_total`` is ``-inf``; the caller decides how
        to recover.
    log_total : float
        ``logsumexp(l)``: the log of the sum of the unnormalised weights.
    """
    lw = np.asarray(log_weights, dtype=np.float64)
    if lw.ndim != 1 or lw.size == 0:
        raise ValueError(f"log weights must be a non-empty 1-D array, got shape {lw.shape}")
    lw = np.where(np.isnan(lw), -np.inf, lw)
    top = float(lw.max())
    if not np.isfinite(top):
        return np.zeros_like(lw), -np.inf
    e = np.exp(lw - top)
    s = float(e.sum())
    return e / s, top + float(np.log(s))


def effective_sample_size(weights: ArrayLike) -> float:
    """Effective sample size ``1 / sum(w_i^2)`` of normalised weights (Probabilistic Robotics 4.3.4).

    Parameters
    ----------
    weights : (N,) array_like
        Non-negative weights (normalised here).

    Returns
    -------
    float
        Between 1 (one particle carries all the weight) and ``N`` (uniform weights).
    """
    w = _check_weights(weights)
    return float(1.0 / np.dot(w, w))
