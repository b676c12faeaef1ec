"""Clusters of a particle set: the places a Monte Carlo localization cloud holds
(:func:`particle_clusters`), used to tell one converged cloud from rival hypotheses
(:meth:`probmap.filters.mcl.MonteCarloLocalization.hypotheses`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap.filters.particle import weighted_pose_covariance, weighted_pose_mean

__all__ = ["Hypothesis", "particle_clusters"]


@dataclass(frozen=True)
class Hypothesis:
    """One cluster of particles: a place the robot may be (:func:`particle_clusters`).

    Attributes
    ----------
    weight : float
        Total weight of its particles.
    mean : (3,) ndarray
        Their weighted mean pose (m, rad).
    spread : float
        Their positional spread ``sqrt(var_x + var_y)`` (m).
    n_particles : int
    """

    weight: float
    mean: NDArray[np.float64]
    spread: float
    n_particles: int


def particle_clusters(
    particles: ArrayLike, weights: ArrayLike, cell: float = 0.5, min_weight: float = 0.05
) -> list[Hypothesis]:
    """The places a particle set holds: particles in touching cells of ``cell`` metres (8
    neighbours) form one cluster; clusters of at least ``min_weight`` are returned, heaviest
    first.

    A weighted spread over all particles cannot tell one wide cloud from two tight ones far
    apart (a symmetric building); the clusters can.

    Parameters
    ----------
    particles : (N, 3) array_like
        Poses (m, rad).
    weights : (N,) array_like
        Normalised weights.
    cell : float
        Cell size (m).
    min_weight : float
        Lightest cluster reported.

    Returns
    -------
    list of Hypothesis

    Examples
    --------
    >>> import numpy as np
    >>> p = np.zeros((4, 3)); p[2:, 0] = 10.0
    >>> [round(h.weight, 2) for h in particle_clusters(p, np.full(4, 0.25))]
    [0.5, 0.5]
    """
    from scipy import ndimage

    p = np.asarray(particles, dtype=np.float64).reshape(-1, 3)
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    if w.shape != (p.shape[0],) or p.shape[0] == 0:
        raise ValueError(f"need particles (N, 3) and weights (N,), got {p.shape}, {w.shape}")
    if not cell > 0:
        raise ValueError(f"cell must be positive, got {cell}")
    size = float(cell)
    while True:  # a set spread over a huge area: coarser cells keep the label image small
        cells = np.floor(p[:, :2] / size).astype(np.int64)
        lo = cells.min(axis=0)
        span = cells.max(axis=0) - lo + 1
        if span[0] * span[1] <= 4_000_000:
            break
        size *= 2.0
    occupied = np.zeros((int(span[0]), int(span[1])), dtype=bool)
    ij = cells - lo
    occupied[ij[:, 0], ij[:, 1]] = True
    labels, count = ndimage.label(occupied, structure=np.ones((3, 3), dtype=bool))
    of = labels[ij[:, 0], ij[:, 1]] - 1
    mass = np.bincount(of, weights=w, minlength=count)
    out = []
    for c in np.argsort(-mass):
        if mass[c] < min_weight or mass[c] <= 0:
            break
        sel = of == c
        wc = w[sel] / mass[c]
        mean = weighted_pose_mean(p[sel], wc)
        cov = weighted_pose_covariance(p[sel], wc, mean)
        spread = math.sqrt(max(cov[0, 0] + cov[1, 1], 0.0))
        out.append(Hypothesis(float(mass[c]), mean, spread, int(sel.sum())))
    return out
