"""Monte Carlo localization on a simulated world: ``probmap demo --localize``.

The world is the cluttered floor plan of :mod:`probmap.sim.localization`; this module runs
global localization in it and writes the trajectory.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from probmap._atomic import atomic_outputs, atomic_write

__all__ = ["run_localize_demo"]


def _write_csv_atomic(path: Path, header: list[str], rows: NDArray[np.float64]) -> None:
    with atomic_write(path, "w") as fh:
        wr = csv.writer(fh)
        wr.writerow(header)
        for row in rows:
            wr.writerow([f"{v:.6f}" for v in row])


def run_localize_demo(out_dir: str | os.PathLike[str], seed: int = 0) -> dict[str, float]:
    """Global localization with augmented MCL on the simulated world; write the results.

    Writes ``out_dir/trajectory.csv`` (step, x, y, theta, spread and the true pose).

    Returns
    -------
    dict
        ``steps``, ``converged_at`` (first update from which the error stays under 0.3 m,
        -1 if never), ``median_error_m`` and ``p95_error_m`` after convergence.
    """
    from probmap.filters.mcl import FreeSpaceSampler, MCLConfig, MonteCarloLocalization
    from probmap.models.likelihood_field import LikelihoodField
    from probmap.models.sampling import OdometryMotionModel
    from probmap.sim.localization import simulate_localization_world

    out = Path(out_dir)
    world = simulate_localization_world(seed)
    lf = LikelihoodField(
        world.spec, world.occupied, max_range=world.max_range, sigma_hit=0.3, z_hit=0.5, z_rand=0.5
    )
    free = FreeSpaceSampler(world.spec, lf.distance > 0.2)
    rng = np.random.default_rng(seed)
    mcl = MonteCarloLocalization.uniform(
        lf,
        OdometryMotionModel(0.1, 0.1, 0.1, 0.1),
        rng,
        free,
        MCLConfig(n_particles=10000, augmented=True),
    )
    rows = []
    errors = []
    for k in range(1, len(world.poses)):
        est = mcl.update_scan(
            world.odometry[k - 1], world.odometry[k], world.ranges[k], world.angles
        )
        p = est.best_cluster
        errors.append(float(np.hypot(*(p[:2] - world.poses[k, :2]))))
        rows.append([k, *p, est.spread, *world.poses[k]])
    err = np.asarray(errors)
    bad = np.flatnonzero(err >= 0.3)
    converged = 0 if bad.size == 0 else int(bad[-1]) + 1
    with atomic_outputs():  # creates a missing out_dir (removed again if the write fails)
        _write_csv_atomic(
            out / "trajectory.csv",
            ["step", "x", "y", "theta", "spread", "true_x", "true_y", "true_theta"],
            np.asarray(rows),
        )
    after = err[converged:] if converged < err.size else err[-1:]
    return {
        "steps": float(err.size),
        "converged_at": float(converged + 1 if converged < err.size else -1),
        "median_error_m": float(np.median(after)),
        "p95_error_m": float(np.percentile(after, 95)),
    }
