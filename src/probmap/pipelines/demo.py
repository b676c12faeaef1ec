"""Monte Carlo localization on a simulated world: ``probmap demo --localize``.

The world is the floor plan of :mod:`probmap.grid.simworld` with seeded clutter added so that
its rooms are not all alike (global localization needs a world without exact symmetries);
scans are ray-cast on it with Gaussian range noise, and odometry drifts.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from probmap._atomic import atomic_outputs, atomic_write
from probmap.grid.spec import GridSpec

__all__ = ["LocalizationWorld", "run_localize_demo", "simulate_localization_world"]


@dataclass(frozen=True, eq=False)
class LocalizationWorld:
    """A true map and a robot run in it.

    Attributes
    ----------
    spec : GridSpec
    occupied : (H, W) bool ndarray
        True map, indexed ``[iy, ix]``.
    poses : (S, 3) ndarray
        True robot poses (m, rad).
    odometry : (S, 3) ndarray
        Drifting odometry poses.
    ranges : (S, B) ndarray
        Scans (m); ``max_range`` for no return.
    angles : (B,) ndarray
        Beam angles (rad).
    max_range : float
    """

    spec: GridSpec
    occupied: NDArray[np.bool_]
    poses: NDArray[np.float64]
    odometry: NDArray[np.float64]
    ranges: NDArray[np.float64]
    angles: NDArray[np.float64]
    max_range: float


def simulate_localization_world(
    seed: int = 0,
    *,
    n_beams: int = 60,
    range_noise: float = 0.02,
    odometry_noise: tuple[float, float] = (0.05, 0.05),
    resolution: float = 0.05,
) -> LocalizationWorld:
    """Simulate a run through a cluttered floor plan.

    Parameters
    ----------
    seed : int
        Seeds the clutter, the route wobble, the range noise and the odometry drift.
    n_beams : int
        Beams over a 180 degree field of view.
    range_noise : float
        Range noise standard deviation (m).
    odometry_noise : (float, float)
        Odometry drift per metre travelled (m/m, rad/m).
    resolution : float
        Map cell size (m).
    """
    from probmap.grid.forward import BeamModel
    from probmap.grid.simworld import floor_plan, simulate_laser_world

    rng = np.random.default_rng(seed)
    base = simulate_laser_world(
        seed=seed, resolution=resolution, n_beams=n_beams, max_range=8.0, step=0.25
    )
    occ, spec = floor_plan(resolution)
    occ = occ.copy()
    poses = base.poses
    # Clutter: a fixed layout (same for every seed) of boxes in the rooms, each room unlike
    # the others, so that few places look alike; boxes keep 0.4 m clear of the route.
    layout = np.random.default_rng(12345)
    r = resolution
    for room_x in np.arange(0.0, 20.0, 4.0):
        for y_lo, y_hi in ((0.5, 4.5), (7.5, 11.5)):
            placed = 0
            for _ in range(60):
                if placed == 4:
                    break
                w, h = layout.uniform(0.3, 1.0, size=2)
                cx = room_x + layout.uniform(0.5, 3.5)
                cy = layout.uniform(y_lo, y_hi)
                gap_x = np.maximum(np.abs(poses[:, 0] - cx) - w / 2, 0.0)
                gap_y = np.maximum(np.abs(poses[:, 1] - cy) - h / 2, 0.0)
                if np.hypot(gap_x, gap_y).min() < 0.4:
                    continue
                i0, i1 = int((cx - w / 2) / r), int((cx + w / 2) / r) + 1
                j0, j1 = int((cy - h / 2) / r), int((cy + h / 2) / r) + 1
                occ[j0:j1, i0:i1] = True
                placed += 1
    angles = np.linspace(-np.pi / 2, np.pi / 2, n_beams)
    caster = BeamModel(spec, occ, max_range=8.0)
    ranges = caster.expected_ranges(poses, angles)
    hit = ranges < 8.0
    ranges = np.where(hit, np.clip(ranges + rng.normal(0, range_noise, ranges.shape), 0, 8.0), 8.0)
    odo = poses.copy()
    for k in range(1, len(poses)):
        d = poses[k, :2] - poses[k - 1, :2]
        c, s = math.cos(poses[k - 1, 2]), math.sin(poses[k - 1, 2])
        fwd, lat = c * d[0] + s * d[1], -s * d[0] + c * d[1]
        dth = poses[k, 2] - poses[k - 1, 2]
        dist = float(np.hypot(*d))
        fwd += rng.normal(0, odometry_noise[0] * dist + 1e-12)
        dth += rng.normal(0, odometry_noise[1] * dist + 1e-12)
        c, s = math.cos(odo[k - 1, 2]), math.sin(odo[k - 1, 2])
        odo[k] = odo[k - 1] + np.array([c * fwd - s * lat, s * fwd + c * lat, dth])
    return LocalizationWorld(spec, occ, poses, odo, ranges, angles, 8.0)


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
    from probmap.grid.forward import LikelihoodField
    from probmap.models.sampling import OdometryMotionModel

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
