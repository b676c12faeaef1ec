"""Numba kernels of the beam model (private; see :mod:`probmap.models.beam`).

The beam model's log-likelihood ``log p(z | z*)`` of one reading (Probabilistic Robotics eq. 6.12,
Table 6.1), and the same over flat arrays. The MAP mapper's kernels
(:mod:`probmap.mapping._map_kernels`) call :func:`beam_log_likelihood` for every cell of every
beam's window; :meth:`probmap.models.beam.BeamModelParams.log_likelihood` calls
:func:`beam_log_likelihoods`. The kernels take plain scalars and contiguous arrays and trust
their inputs.
"""

from __future__ import annotations

import math

from numba import njit

_SQRT2 = math.sqrt(2.0)
_SQRT2PI = math.sqrt(2.0 * math.pi)


@njit(cache=True)
def beam_log_likelihood(z, zs, max_range, z_hit, z_short, z_max, z_rand, sigma, lam):
    """``log p(z | z*)`` of the beam model mixture (Probabilistic Robotics eq. 6.12, Table 6.1).

    The hit Gaussian is truncated to ``[0, max_range]`` and normalised (eq. 6.4), the short
    exponential to ``[0, z*]`` (eq. 6.7); ``z >= max_range`` is the max-range point mass alone.
    """
    p = 0.0
    if z >= max_range:
        p = z_max
    else:
        norm = 0.5 * (
            math.erf((max_range - zs) / (sigma * _SQRT2)) - math.erf((0.0 - zs) / (sigma * _SQRT2))
        )
        if norm > 1e-300:
            d = z - zs
            p += z_hit * math.exp(-0.5 * d * d / (sigma * sigma)) / (sigma * _SQRT2PI * norm)
        if z <= zs and zs > 0.0:
            p += z_short * lam * math.exp(-lam * z) / (1.0 - math.exp(-lam * zs))
        p += z_rand / max_range
    return math.log(p)


@njit(cache=True)
def beam_log_likelihoods(z, zs, max_range, params, out):
    """:func:`beam_log_likelihood` over flat arrays ``z``, ``zs`` into ``out``."""
    for i in range(z.shape[0]):
        out[i] = beam_log_likelihood(
            z[i], zs[i], max_range, params[0], params[1], params[2], params[3], params[4],
            params[5],
        )  # fmt: skip
