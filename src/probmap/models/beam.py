"""The beam model of range finders (Probabilistic Robotics section 6.3, Table 6.1, eq. 6.12).

A reading ``z`` of a beam whose expected range is ``z*`` is explained by a mixture of four
causes: the obstacle at ``z*`` with Gaussian noise (hit), an unexpected object before it
(short), a failure that reads the maximum range (max) and random noise (rand).
:class:`BeamModelParams` holds the intrinsic parameters of that mixture and evaluates it; the
MAP mapper (:mod:`probmap.mapping.map_mapping`) and the EM fit (:mod:`probmap.grid.fit`) share it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["BeamModelParams"]


@dataclass(frozen=True)
class BeamModelParams:
    """Intrinsic parameters of the beam model (Probabilistic Robotics Table 6.1, eq. 6.12).

    Defaults are those of :class:`probmap.grid.forward.BeamModel`.

    Parameters
    ----------
    z_hit, z_short, z_max, z_rand : float
        Mixture weights of the hit, short, max-range and random components; they must sum to
        1, and ``z_max`` and ``z_rand`` must be positive so that every reading has a positive
        likelihood (the objective can never become infinite).
    sigma_hit : float
        Standard deviation of the hit Gaussian, metres.
    lambda_short : float
        Rate of the short-reading exponential, 1/m.
    """

    z_hit: float = 0.8
    z_short: float = 0.1
    z_max: float = 0.05
    z_rand: float = 0.05
    sigma_hit: float = 0.2
    lambda_short: float = 0.1

    def __post_init__(self) -> None:
        for name in ("z_hit", "z_short", "z_max", "z_rand", "sigma_hit", "lambda_short"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0.0):
                raise ValueError(f"BeamModelParams.{name} must be a finite number >= 0, got {v!r}")
        for name in ("z_max", "z_rand", "sigma_hit", "lambda_short"):
            if not getattr(self, name) > 0.0:
                raise ValueError(
                    f"BeamModelParams.{name} must be > 0 (it keeps every likelihood positive)"
                )
        total = self.z_hit + self.z_short + self.z_max + self.z_rand
        if abs(total - 1.0) > 1e-6:
            raise ValueError(
                f"BeamModelParams mixture weights z_hit + z_short + z_max + z_rand must sum to 1,"
                f" got {total:.6g}"
            )

    def as_array(self) -> NDArray[np.float64]:
        """``[z_hit, z_short, z_max, z_rand, sigma_hit, lambda_short]`` for the kernels."""
        return np.array(
            [
                self.z_hit,
                self.z_short,
                self.z_max,
                self.z_rand,
                self.sigma_hit,
                self.lambda_short,
            ]
        )

    def log_likelihood(self, z: ArrayLike, zs: ArrayLike, max_range: float) -> NDArray[np.float64]:
        """``log p(z | z*)`` elementwise for readings ``z`` and expected ranges ``zs`` (m).

        Examples
        --------
        >>> p = BeamModelParams()
        >>> bool(p.log_likelihood(2.0, 2.0, 10.0) > p.log_likelihood(1.0, 2.0, 10.0))
        True
        >>> round(float(p.log_likelihood(10.0, 3.0, 10.0)), 4)  # log z_max
        -2.9957
        """
        from probmap.models import _beam_kernels as _k

        zz, ss = np.broadcast_arrays(np.asarray(z, float), np.asarray(zs, float))
        zf = np.ascontiguousarray(zz.ravel())
        out = np.empty(zf.shape[0])
        _k.beam_log_likelihoods(
            zf, np.ascontiguousarray(ss.ravel()), float(max_range), self.as_array(), out
        )
        return out.reshape(zz.shape)
