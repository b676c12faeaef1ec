"""Robust parts of Monte Carlo localization's fused update, for maps and odometry that are off.

:meth:`probmap.filters.mcl.MonteCarloLocalization.update_scan` runs
:func:`mcl_sample_and_weight_robust` instead of the plain fused pass
(:func:`probmap.filters.mcl.mcl_sample_and_weight_scan`) while either part is on:

- **Beams through walls** (``wall_margin``). The likelihood field (Probabilistic Robotics
  section 6.4) looks only at where a beam ends. Where the scans see walls that the map lacks
  (other passes saw through there: doors, glass, furniture moved), few beams end near the map's
  obstacles at the right pose, and a pose turned by tens of degrees, whose beams cross the map's
  walls and end on others, can fit better. The beam model (section 6.3) would not take that
  pose: a reading much longer than the range to the first wall is a random one. Here such a
  beam scores the field's floor, as an endpoint far from any obstacle
  (:meth:`probmap.models.likelihood_field.LikelihoodField.log_likelihood_sum_walls`).
- **Reversed odometry** (``reverse_fraction``). Some odometry logs reversing as forward driving
  (Freiburg 079); a few particles that move by the odometry's translation reversed keep a
  hypothesis where the robot went, which the scans then pick.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap.filters import _kernels as _k
from probmap.models.sampling import odometry_deltas, odometry_noise_std

__all__ = ["mcl_sample_and_weight_robust"]


def mcl_sample_and_weight_robust(
    mcl: Any,
    odom_prev: ArrayLike,
    odom_cur: ArrayLike,
    lx: NDArray[np.float64],
    ly: NDArray[np.float64],
    sensor_offset: ArrayLike,
) -> NDArray[np.float64]:
    """Table 8.2 lines 4-5 fused (odometry, Table 5.6; likelihood field, Table 6.3) with the
    robust parts that ``mcl`` asks for (see the module's text).

    Parameters
    ----------
    mcl : MonteCarloLocalization
        Its particles ``(N, 3)`` are **moved in place**; its likelihood field ``sensor``,
        odometry model ``motion``, random generator ``rng``, ``wall_margin`` (m, or None) and
        ``reverse_fraction`` (every ``round(1 / reverse_fraction)``-th particle, from a random
        offset, moves by the odometry's translation reversed; 0: none) are used.
    odom_prev, odom_cur : (3,) array_like
        Odometry poses before and after the step (odometry frame).
    lx, ly : (B,) ndarray
        Valid scan endpoints in the robot frame (m).
    sensor_offset : (3,) array_like
        The laser's pose in the robot frame (m, rad).

    Returns
    -------
    (N,) ndarray
        Log-likelihood of the scan for each moved particle.
    """
    field, rng = mcl.sensor, mcl.rng
    r1, tr, r2 = (float(v) for v in odometry_deltas(odom_prev, odom_cur))
    sd1, sdt, sd2 = odometry_noise_std(r1, tr, r2, mcl.motion.alphas, mcl.motion.unit_step)
    particles = mcl.particles
    n = particles.shape[0]
    noise = rng.standard_normal((n, 3))
    ll = np.zeros(n)
    f = field.frame
    frac = float(mcl.reverse_fraction)
    every = max(1, round(1.0 / frac)) if frac > 0 else 0
    o = np.asarray(sensor_offset, dtype=np.float64).reshape(-1)[:2]
    bx, by = np.ascontiguousarray(lx), np.ascontiguousarray(ly)
    angle, length = field.wall_beams(bx, by, o)
    walls = mcl.wall_margin is not None
    margin = float(mcl.wall_margin) / f.resolution if walls else 0.0
    occ, slots, pool, cells, state, block, quantum = field.wall_cache()
    _k.odometry_predict_and_weight_robust(
        particles, noise, r1, tr, r2, sd1, sdt, sd2, bx, by, field.table, f.x0, f.y0,
        1.0 / f.resolution, field.outside, walls, float(o[0]), float(o[1]), angle, length, margin,
        occ, slots, pool, cells, state, block, quantum, every, int(rng.integers(every or 1)), ll,
    )  # fmt: skip
    return ll
