"""A simulated floor plan with a laser robot: ground truth for mapping tests and ``probmap demo``.

Everything is generated from a seed (nothing to download): a rectangular building with rooms,
doors and a few pillars (:func:`floor_plan`), a closed tour through every room
(:func:`floor_plan_route`), and 2-D laser scans cast on the true map with Gaussian range noise
and, optionally, odometry drift (:func:`simulate_laser_world`, built from the shared steps of
:mod:`probmap.sim.laser`). The labelled building of :mod:`probmap.sim.semantic` and the
cluttered one of :mod:`probmap.sim.localization` are this building too.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from probmap.grid.raycast import cast_rays
from probmap.grid.spec import GridSpec
from probmap.sim.laser import (
    SimulatedLaserWorld,
    drift_odometry,
    interpolate_route,
    noisy_ranges,
    poses_along,
)

__all__ = ["floor_plan", "floor_plan_route", "simulate_laser_world"]


def floor_plan(
    resolution: float = 0.05, size: tuple[float, float] = (20.0, 12.0)
) -> tuple[NDArray[np.bool_], GridSpec]:
    """A building of ``size`` metres: outer walls, two rows of rooms off a corridor, pillars.

    Returns the true occupancy (H, W) and its GridSpec (origin (0, 0)).
    """
    w_m, h_m = size
    spec = GridSpec(resolution, (0.0, 0.0), (round(h_m / resolution), round(w_m / resolution)))
    occ = np.zeros(spec.shape, dtype=bool)
    t = max(1, round(0.15 / resolution))  # wall thickness in cells

    def box(x0: float, x1: float, y0: float, y1: float) -> None:
        i0, i1 = round(x0 / resolution), round(x1 / resolution)
        j0, j1 = round(y0 / resolution), round(y1 / resolution)
        occ[max(j0, 0) : max(j1, j0 + 1), max(i0, 0) : max(i1, i0 + 1)] = True

    r = resolution
    # outer walls
    box(0, w_m, 0, t * r)
    box(0, w_m, h_m - t * r, h_m)
    box(0, t * r, 0, h_m)
    box(w_m - t * r, w_m, 0, h_m)
    # corridor between y = 5 and y = 7, rooms below and above, 4 m wide, doors 1 m wide
    for y_wall in (5.0, 7.0):
        x = 0.0
        while x < w_m - 1e-9:
            door = x + 1.5
            box(x, door, y_wall, y_wall + t * r)
            box(door + 1.0, min(x + 4.0, w_m), y_wall, y_wall + t * r)
            x += 4.0
    for x_wall in np.arange(4.0, w_m - 1e-9, 4.0):
        box(x_wall, x_wall + t * r, 0, 5.0)
        box(x_wall, x_wall + t * r, 7.0, h_m)
    # pillars and furniture
    for cx, cy in ((2.0, 2.0), (10.0, 9.5), (14.0, 2.5), (18.0, 10.0), (6.0, 10.0)):
        box(cx - 0.3, cx + 0.3, cy - 0.3, cy + 0.3)
    return occ, spec


def floor_plan_route(size: tuple[float, float] = (20.0, 12.0)) -> NDArray[np.float64]:
    """Waypoints (N, 2) of a tour of :func:`floor_plan`: along the corridor, into every room
    through its door and back, from the west end of the corridor to its east end (metres).
    Rooms above the corridor less than 3 m deep (``size[1] < 10``) are left out."""
    w_m, h_m = size
    # the corridor lies between y = 5 and 7 m whatever the size: the rooms above it are
    # h_m - 7 m deep, and the tour enters them only when they are deep enough to turn in
    # (3 m; 5 m at the default size), so that it never crosses the outer wall
    upper = h_m - 7.0 >= 3.0
    pts: list[tuple[float, float]] = [(0.8, 6.0)]
    x = 0.0
    while x < w_m - 1e-9:
        door_x = x + 2.0
        pts += [(door_x, 6.0), (door_x, 3.0), (x + 1.2, 1.5), (x + 3.0, 1.5), (door_x, 3.0)]
        if upper:
            top = h_m - 1.2
            pts += [(door_x, 6.0), (door_x, 9.0), (x + 3.0, top), (x + 1.2, top), (door_x, 9.0)]
        pts += [(door_x, 6.0)]
        x += 4.0
    pts.append((w_m - 0.8, 6.0))
    return np.asarray(pts)


# simulate_labelled_world (sim/semantic.py) takes these keywords too, with the same meaning: the
# same floor plan and tour; each world keeps its own typed, documented signature.
def simulate_laser_world(
    *,
    seed: int = 0,
    resolution: float = 0.05,
    size: tuple[float, float] = (20.0, 12.0),
    step: float = 0.25,
    n_beams: int = 181,
    fov: float = np.pi,
    max_range: float = 8.0,
    range_noise: float = 0.01,
    pose_noise: tuple[float, float] = (0.0, 0.0),
    dropout: float = 0.0,
) -> SimulatedLaserWorld:
    """Simulate a laser robot touring :func:`floor_plan`.

    Parameters
    ----------
    seed : int
        Seed of the random generator; equal seeds give equal worlds.
    resolution : float
        Cell size of the true map, metres.
    size : tuple of float
        Building size (width, height) in metres; multiples of 4 m wide work best.
    step : float
        Distance between scans along the route, metres.
    n_beams, fov : int, float
        Beams per scan spread over ``fov`` radians centred on the heading.
    max_range : float
        Sensor maximum range, metres; beams with no return read exactly ``max_range``.
    range_noise : float
        Standard deviation of Gaussian range noise, metres.
    pose_noise : tuple of float
        Odometry drift per metre travelled: standard deviations (metres, radians).
    dropout : float
        Probability that a beam returns NaN (a dropped reading).

    Returns
    -------
    SimulatedLaserWorld
    """
    rng = np.random.default_rng(seed)
    truth, spec = floor_plan(resolution, size)
    poses = poses_along(interpolate_route(floor_plan_route(size), step), rng, 0.05)
    angles = np.linspace(-fov / 2, fov / 2, n_beams)
    ranges = noisy_ranges(
        cast_rays(truth, spec, poses, angles, max_range), max_range, rng, range_noise, dropout
    )
    odo = drift_odometry(poses, rng, pose_noise)
    times = np.arange(len(poses), dtype=np.float64) * 0.2
    return SimulatedLaserWorld(truth, spec, poses, odo, ranges, angles, float(max_range), times)
