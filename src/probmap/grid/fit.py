"""Fitting the beam model's intrinsic parameters to data by EM (Probabilistic Robotics Table 6.2).

Given readings ``z_i`` and the ranges ``z*_i`` a map predicts for them (by ray casting), each
reading is attributed softly to the four causes of the beam model (E-step) and the mixture
weights and component parameters are re-estimated from those attributions (M-step):

- ``z_c = (1/|Z|) sum_i e_i,c`` for the weights,
- ``sigma_hit^2 = sum_i e_i,hit (z_i - z*_i)^2 / sum_i e_i,hit`` (Table 6.2),
- ``lambda_short`` maximising ``sum_i e_i,short log p_short(z_i | z*_i)`` exactly, i.e. with the
  truncation normaliser ``1 / (1 - exp(-lambda z*_i))`` of eq. 6.7 (Table 6.2's closed form
  ``sum e / sum e z`` ignores it and is only its limit for long ``z*``). The weighted
  log-likelihood of a truncated exponential is concave in lambda, so bisection on its
  derivative finds the maximiser.

Unlike the book's listing, the E-step weighs each component by its current mixture weight
(``e_i,c ∝ z_c p_c(z_i)``), which is what makes the procedure EM. The sigma update ignores the
truncation of the Gaussian to ``[0, z_max]`` (negligible unless ``z*`` is within a few sigma of
either end).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._deprecation import moved
from probmap.models.beam import BeamModelParams

__all__ = ["FitResult", "component_densities", "fit_beam_model"]

# ``fit_log`` (reading a log) moved to probmap.pipelines.fit; the old path works for one release.
__getattr__ = moved(__name__, {"fit_log": "probmap.pipelines.fit"})


@dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`fit_beam_model`.

    Attributes
    ----------
    params : BeamModelParams
        The fitted parameters.
    log_likelihood : tuple of float
        Mean log-likelihood per reading after each iteration (index 0: the initial guess).
    iterations : int
    converged : bool
        The mean log-likelihood changed by less than ``tol`` in the last iteration.
    readings : int
        Readings used.
    """

    params: BeamModelParams
    log_likelihood: tuple[float, ...]
    iterations: int
    converged: bool
    readings: int


def component_densities(
    z: NDArray[np.float64],
    zs: NDArray[np.float64],
    max_range: float,
    sigma: float,
    lam: float,
) -> NDArray[np.float64]:
    """Densities ``p_hit, p_short, p_max, p_rand`` of each reading (eqs. 6.4-6.10), shape (4, N).

    ``p_max`` is the point mass at ``z_max`` (1 there, 0 elsewhere).
    """
    from scipy.special import erf

    below = z < max_range
    norm = 0.5 * (erf((max_range - zs) / (sigma * math.sqrt(2))) + erf(zs / (sigma * math.sqrt(2))))
    hit = np.where(
        below,
        np.exp(-0.5 * ((z - zs) / sigma) ** 2)
        / (sigma * math.sqrt(2 * math.pi) * np.maximum(norm, 1e-300)),
        0.0,
    )
    ok_short = below & (z <= zs) & (zs > 0)
    denom = -np.expm1(-lam * np.where(zs > 0, zs, 1.0))
    short = np.where(ok_short, lam * np.exp(-lam * z) / denom, 0.0)
    pmax = np.where(below, 0.0, 1.0)
    rand = np.where(below, 1.0 / max_range, 0.0)
    return np.stack([hit, short, pmax, rand])


def _check(ranges: ArrayLike, expected: ArrayLike, max_range: float) -> tuple[NDArray, NDArray]:
    z = np.asarray(ranges, dtype=np.float64)
    zs = np.asarray(expected, dtype=np.float64)
    if z.shape != zs.shape:
        raise ValueError(f"ranges {z.shape} and expected ranges {zs.shape} must have one shape")
    if not (math.isfinite(max_range) and max_range > 0):
        raise ValueError(f"max_range must be a finite number > 0 m, got {max_range}")
    keep = np.isfinite(z) & np.isfinite(zs) & (z >= 0) & (zs >= 0)
    z = np.minimum(z[keep], max_range)
    zs = np.minimum(zs[keep], max_range)
    if z.size < 10:
        raise ValueError(f"need at least 10 valid readings to fit the beam model, got {z.size}")
    return z, zs


def _lambda_step(e: NDArray, z: NDArray, zs: NDArray, lam0: float) -> float:
    """Maximiser of ``sum e (log lam - lam z - log(1 - exp(-lam zs)))`` by bisection."""
    w = e.sum()
    if w <= 1e-12:
        return lam0

    def slope(lam: float) -> float:
        x = lam * zs
        # zs * exp(-x) / (1 - exp(-x)) = zs / expm1(x), with the limit 1/lam at x -> 0
        tail = np.where(x > 1e-12, zs / np.expm1(np.clip(x, 1e-12, 700.0)), 1.0 / lam)
        return float(w / lam - np.sum(e * z) - np.sum(e * tail))

    lo, hi = 1e-6, 1e4
    if slope(lo) <= 0:
        return lo
    if slope(hi) >= 0:
        return hi
    for _ in range(80):
        mid = math.sqrt(lo * hi)
        if slope(mid) > 0:
            lo = mid
        else:
            hi = mid
    return math.sqrt(lo * hi)


def fit_beam_model(
    ranges: ArrayLike,
    expected: ArrayLike,
    max_range: float,
    *,
    init: BeamModelParams | None = None,
    max_iterations: int = 200,
    tol: float = 1e-7,
) -> FitResult:
    """Fit the beam model's intrinsic parameters by EM (Table 6.2).

    Parameters
    ----------
    ranges : array_like
        Measured ranges ``z_i`` in metres (any shape; NaN or negative readings are ignored,
        readings beyond ``max_range`` count as max-range readings).
    expected : array_like
        Ranges ``z*_i`` (m) the map predicts for the same beams, same shape.
    max_range : float
        The sensor's maximum range ``z_max`` in metres.
    init : BeamModelParams, optional
        Starting point (default :class:`BeamModelParams`).
    max_iterations : int
        Iteration limit.
    tol : float
        Stop when the mean log-likelihood per reading changes by less than this.

    Returns
    -------
    FitResult

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> zs = rng.uniform(1, 5, 5000)
    >>> z = zs + rng.normal(0, 0.1, zs.size)
    >>> fit = fit_beam_model(z, zs, 10.0)
    >>> round(fit.params.sigma_hit, 2), fit.params.z_hit > 0.95
    (0.1, True)
    """
    z, zs = _check(ranges, expected, float(max_range))
    p = init or BeamModelParams()
    weights = np.array([p.z_hit, p.z_short, p.z_max, p.z_rand])
    sigma, lam = p.sigma_hit, p.lambda_short
    floor = 1e-6  # z_max and z_rand stay positive, so no reading ever has zero likelihood
    history: list[float] = []
    converged = False
    it = 0
    for it in range(max_iterations + 1):
        dens = component_densities(z, zs, max_range, sigma, lam) * weights[:, None]
        total = dens.sum(axis=0)
        history.append(float(np.mean(np.log(total))))
        if it > 0 and abs(history[-1] - history[-2]) < tol:
            converged = True
            break
        if it == max_iterations:
            break
        e = dens / total  # E-step: responsibilities of the four causes
        weights = np.maximum(e.mean(axis=1), floor)
        weights /= weights.sum()
        sw = e[0].sum()
        if sw > 1e-12:
            sigma = max(float(np.sqrt(np.sum(e[0] * (z - zs) ** 2) / sw)), 1e-4)
        lam = _lambda_step(e[1], z, zs, lam)
    params = BeamModelParams(
        z_hit=float(weights[0]),
        z_short=float(weights[1]),
        z_max=float(weights[2]),
        z_rand=float(1.0 - weights[0] - weights[1] - weights[2]),
        sigma_hit=sigma,
        lambda_short=lam,
    )
    return FitResult(params, tuple(history), it, converged, int(z.size))
