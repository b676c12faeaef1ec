"""Data association for landmark SLAM: Mahalanobis gating and maximum likelihood.

Pure array functions shared by the EKF and SEIF estimators (Probabilistic Robotics, Table 10.2
lines 16-18 and section 10.3.3). The estimator supplies, for each candidate landmark ``j``, the
predicted measurement ``z_hat[j]`` and innovation covariance ``S[j]``; these helpers only compare.
The input checks every landmark estimator makes (initial state, observations) live here too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from probmap._typing import FloatArray, IntArray
from probmap.geometry.se2 import wrap_angle

__all__ = [
    "NEW",
    "REJECTED",
    "Association",
    "associate_ml",
    "chi2_gate",
    "innovation",
    "mahalanobis_squared",
    "validate_control",
    "validate_initial_state",
    "validate_observations",
]

NEW = -1
"""Association code: the observation is far from every landmark, start a new one."""
REJECTED = -2
"""Association code: ambiguous (between the gates) or lost the mutual-exclusion contest."""


def chi2_gate(probability: float, dof: int = 2) -> float:
    """Chi-square quantile used as a Mahalanobis gate, e.g. ``chi2_gate(0.99) = 9.21``."""
    if not 0.0 < probability < 1.0:
        raise ValueError(f"gate probability must be in (0, 1), got {probability}")
    from scipy.stats import chi2

    return float(chi2.ppf(probability, dof))


def innovation(z: ArrayLike, z_hat: ArrayLike) -> FloatArray:
    """Range-bearing innovations ``z - z_hat`` with the bearing wrapped; broadcasts (..., 2)."""
    nu = np.asarray(z, dtype=np.float64) - np.asarray(z_hat, dtype=np.float64)
    nu[..., 1] = wrap_angle(nu[..., 1])
    return nu


def mahalanobis_squared(z: ArrayLike, z_hat: ArrayLike, S: ArrayLike) -> FloatArray:
    """Squared Mahalanobis distances between every observation and every candidate.

    Parameters
    ----------
    z : array_like, shape (k, 2)
        Observations (range, bearing).
    z_hat : array_like, shape (n, 2)
        Predicted observations of the n candidates.
    S : array_like, shape (n, 2, 2)
        Innovation covariances of the candidates (symmetric positive definite).

    Returns
    -------
    ndarray, shape (k, n)
        ``nu^T S^-1 nu`` with the bearing innovation wrapped.
    """
    z = np.asarray(z, dtype=np.float64)
    S = np.asarray(S, dtype=np.float64)
    nu = innovation(z[:, None, :], np.asarray(z_hat, dtype=np.float64)[None, :, :])
    a, b, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
    det = a * d - b * b
    if np.any(det <= 0):
        raise ValueError("innovation covariance is not positive definite")
    # closed-form 2x2 inverse, vectorised over (k, n)
    return (d * nu[..., 0] ** 2 - 2 * b * nu[..., 0] * nu[..., 1] + a * nu[..., 1] ** 2) / det


@dataclass(frozen=True)
class Association:
    """Result of :func:`associate_ml`.

    Attributes
    ----------
    match : ndarray, shape (k,), int64
        Candidate index per observation, or :data:`NEW` / :data:`REJECTED`.
    d2 : ndarray, shape (k,)
        Squared Mahalanobis distance to the chosen (or nearest) candidate; inf without candidates.
    """

    match: IntArray
    d2: FloatArray


def associate_ml(
    z: ArrayLike,
    z_hat: ArrayLike,
    S: ArrayLike,
    *,
    gate: float,
    new_gate: float,
) -> Association:
    """Maximum-likelihood association with Mahalanobis gating and mutual exclusion.

    Each observation goes to the candidate of highest likelihood, i.e. lowest
    ``d2 + log det S`` (Table 10.2, line 17), among those with ``d2 < gate``. Pairs are taken
    greedily in order of cost so that no candidate receives two observations of one scan. An
    observation whose nearest candidate has ``d2 > new_gate`` is marked :data:`NEW`; one that is
    neither matched nor that far is :data:`REJECTED`.

    Parameters
    ----------
    z : array_like, shape (k, 2)
    z_hat : array_like, shape (n, 2)
    S : array_like, shape (n, 2, 2)
    gate : float
        Acceptance gate on d2 (e.g. ``chi2_gate(0.99)``).
    new_gate : float
        Gate above which a new landmark is started (>= ``gate``).
    """
    if new_gate < gate:
        raise ValueError(f"new_gate ({new_gate}) must be >= gate ({gate})")
    z = np.asarray(z, dtype=np.float64).reshape(-1, 2)
    k = z.shape[0]
    S = np.asarray(S, dtype=np.float64).reshape(-1, 2, 2)
    n = S.shape[0]
    match = np.full(k, REJECTED, dtype=np.int64)
    if n == 0:
        match[:] = NEW
        return Association(match, np.full(k, np.inf))
    D2 = mahalanobis_squared(z, z_hat, S)
    logdet = np.log(S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] ** 2)
    cost = np.where(D2 < gate, D2 + logdet[None, :], np.inf)
    nearest = D2.min(axis=1)
    d2 = nearest.copy()
    order = np.argsort(cost, axis=None)
    taken = np.zeros(n, dtype=bool)
    done = np.zeros(k, dtype=bool)
    for flat in order:
        i, j = divmod(int(flat), n)
        if not np.isfinite(cost[i, j]):
            break
        if done[i] or taken[j]:
            continue
        match[i] = j
        d2[i] = D2[i, j]
        done[i] = True
        taken[j] = True
    match[(~done) & (nearest > new_gate)] = NEW
    return Association(match, d2)


def validate_initial_state(
    initial_pose: ArrayLike, initial_covariance: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """The initial pose and covariance of a landmark SLAM estimator, checked.

    Parameters
    ----------
    initial_pose : array_like, shape (3,)
        ``(x, y, theta)`` (m, m, rad).
    initial_covariance : array_like, shape (3, 3)

    Returns
    -------
    mu : ndarray, shape (3,)
    P0 : ndarray, shape (3, 3)
        The covariance made exactly symmetric, ``(P + P^T) / 2``; how definite it must be is
        each estimator's own rule.

    Raises
    ------
    ValueError
        On a wrong shape, a non-finite entry or an asymmetric covariance.
    """
    mu = np.asarray(initial_pose, dtype=np.float64)
    P0 = np.asarray(initial_covariance, dtype=np.float64)
    if mu.shape != (3,) or P0.shape != (3, 3):
        raise ValueError("initial_pose must be (3,) and initial_covariance (3, 3)")
    if not (np.all(np.isfinite(mu)) and np.all(np.isfinite(P0))):
        raise ValueError("initial pose and covariance must be finite")
    if not np.allclose(P0, P0.T):
        raise ValueError("initial_covariance must be a finite symmetric 3x3 matrix")
    return mu.copy(), 0.5 * (P0 + P0.T)


def validate_control(u: ArrayLike) -> FloatArray:
    """One step's control ``u`` as float64 (2,), or :class:`ValueError` when it is not two
    finite numbers (FastSLAM's and GraphSLAM's ``predict``)."""
    c = np.asarray(u, dtype=np.float64)
    if c.shape != (2,) or not np.all(np.isfinite(c)):
        raise ValueError(f"control must be 2 finite numbers, got {c!r}")
    return c


def validate_observations(z: ArrayLike, ids: ArrayLike) -> tuple[FloatArray, IntArray]:
    """One step's observations, checked: ``z`` as ``(k, 2)`` float (range m, bearing rad) and
    ``ids`` as ``(k,)`` int (landmark ids, -1 for unknown).

    Raises
    ------
    ValueError
        When the counts differ, a measurement is not finite or an id is below -1.
    """
    zs = np.asarray(z, dtype=np.float64).reshape(-1, 2) if np.size(z) else np.zeros((0, 2))
    idx = np.asarray(ids, dtype=np.int64).reshape(-1)
    if idx.shape[0] != zs.shape[0]:
        raise ValueError(f"z has {zs.shape[0]} rows but ids has {idx.shape[0]}")
    if not np.all(np.isfinite(zs)):
        raise ValueError("measurements must be finite (NaN or inf found)")
    if np.any(idx < -1):
        raise ValueError("landmark ids must be >= 0, or -1 for unknown")
    return zs, idx
