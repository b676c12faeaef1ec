"""A cluttered floor plan for Monte Carlo localization: ``probmap demo --localize`` and MCL tests.

The world is the building of :func:`probmap.sim.floorplan.floor_plan` with seeded clutter
added so that its rooms are not all alike (global localization needs a world without exact
symmetries). The robot tours it as in :func:`probmap.sim.floorplan.simulate_laser_world`; scans
are ray-cast on the cluttered map by the beam model's caster
(:meth:`probmap.models.beam.BeamModel.expected_ranges`) with Gaussian range noise, and the
odometry drifts (:func:`probmap.sim.laser.drift_odometry`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from probmap.grid.spec import GridSpec
from probmap.models.beam import BeamModel
from probmap.sim.floorplan import floor_plan, simulate_laser_world
from probmap.sim.laser import drift_odometry

__all__ = ["LocalizationWorld", "simulate_localization_world"]


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

    Returns
    -------
    LocalizationWorld
    """
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
    # this sensor clips noisy returns to [0, 8] m (not [1 mm, 8 m) as noisy_ranges does)
    hit = ranges < 8.0
    ranges = np.where(hit, np.clip(ranges + rng.normal(0, range_noise, ranges.shape), 0, 8.0), 8.0)
    odo = drift_odometry(poses, rng, odometry_noise)
    return LocalizationWorld(spec, occ, poses, odo, ranges, angles, 8.0)
