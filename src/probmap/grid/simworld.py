"""A simulated floor plan with a laser robot: ground truth for mapping tests and ``probmap demo``.

Everything is generated from a seed (nothing to download): a rectangular building with rooms,
doors and a few pillars, a closed trajectory through it, and 2-D laser scans cast on the true map
with Gaussian range noise and, optionally, pose noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from probmap.grid.raycast import cast_rays
from probmap.grid.spec import GridSpec


@dataclass(frozen=True, eq=False)
class SimulatedLaserWorld:
    """A true occupancy map and the scans a robot took in it.

    Attributes
    ----------
    truth : ndarray of bool, shape (H, W)
        True occupied cells, indexed ``[iy, ix]``.
    spec : GridSpec
        Geometry of ``truth``.
    poses : ndarray, shape (S, 3)
        True sensor poses ``(x, y, theta)`` (metres, radians).
    odometry : ndarray, shape (S, 3)
        Poses as dead reckoning reports them (true poses with accumulated drift).
    ranges : ndarray, shape (S, B)
        Measured ranges in metres (``max_range`` for no return).
    angles : ndarray, shape (B,)
        Beam angles in the sensor frame, radians.
    max_range : float
        Sensor maximum range, metres.
    times : ndarray, shape (S,)
        Scan timestamps in seconds.
    """

    truth: NDArray[np.bool_]
    spec: GridSpec
    poses: NDArray[np.float64]
    odometry: NDArray[np.float64]
    ranges: NDArray[np.float64]
    angles: NDArray[np.float64]
    max_range: float
    times: NDArray[np.float64]


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


def _route(size: tuple[float, float]) -> NDArray[np.float64]:
    """Waypoints: along the corridor, into every room through its door and back."""
    w_m, _ = size
    pts: list[tuple[float, float]] = [(0.8, 6.0)]
    x = 0.0
    while x < w_m - 1e-9:
        door_x = x + 2.0
        pts += [(door_x, 6.0), (door_x, 3.0), (x + 1.2, 1.5), (x + 3.0, 1.5), (door_x, 3.0)]
        pts += [(door_x, 6.0), (door_x, 9.0), (x + 3.0, 10.8), (x + 1.2, 10.8), (door_x, 9.0)]
        pts += [(door_x, 6.0)]
        x += 4.0
    pts.append((w_m - 0.8, 6.0))
    return np.asarray(pts)


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
    way = _route(size)
    pts = [way[0]]
    for a, b in zip(way[:-1], way[1:], strict=True):
        d = float(np.hypot(*(b - a)))
        n = max(1, int(np.ceil(d / step)))
        for k in range(1, n + 1):
            pts.append(a + (b - a) * k / n)
    xy = np.asarray(pts)
    heading = np.arctan2(np.diff(xy[:, 1]), np.diff(xy[:, 0]))
    heading = np.concatenate([heading, heading[-1:]])
    poses = np.column_stack([xy, heading])
    poses[:, 2] += rng.normal(0.0, 0.05, len(poses))  # wobble so scans see more
    angles = np.linspace(-fov / 2, fov / 2, n_beams)
    ranges = cast_rays(truth, spec, poses, angles, max_range)
    hit = ranges < max_range
    ranges = np.where(hit, ranges + rng.normal(0.0, range_noise, ranges.shape), max_range)
    ranges = np.where(hit, np.clip(ranges, 1e-3, max_range - 1e-6), ranges)
    if dropout > 0:
        ranges[rng.random(ranges.shape) < dropout] = np.nan
    # odometry: integrate noisy relative motions
    odo = poses.copy()
    for k in range(1, len(poses)):
        dx, dy = poses[k, :2] - poses[k - 1, :2]
        c, s = np.cos(poses[k - 1, 2]), np.sin(poses[k - 1, 2])
        fwd, lat = c * dx + s * dy, -s * dx + c * dy
        dth = poses[k, 2] - poses[k - 1, 2]
        dist = float(np.hypot(dx, dy))
        fwd += rng.normal(0, pose_noise[0] * dist + 1e-12)
        dth += rng.normal(0, pose_noise[1] * dist + 1e-12)
        c, s = np.cos(odo[k - 1, 2]), np.sin(odo[k - 1, 2])
        odo[k] = odo[k - 1] + np.array([c * fwd - s * lat, s * fwd + c * lat, dth])
    times = np.arange(len(poses), dtype=np.float64) * 0.2
    return SimulatedLaserWorld(truth, spec, poses, odo, ranges, angles, float(max_range), times)


def map_accuracy(
    classified: NDArray[np.int8],
    grid_spec: GridSpec,
    truth: NDArray[np.bool_],
    truth_spec: GridSpec,
) -> tuple[float, int]:
    """Fraction of classified (non-unknown) cells whose class matches the true map.

    ``classified`` holds 1 occupied, 0 free, -1 unknown on ``grid_spec``; each classified cell is
    compared with the true cell containing its centre (cells outside the truth count as free).
    A cell counts as correct if it is occupied and a true occupied cell lies within one cell of it
    (ray endpoints on a wall face fall on either side of the boundary), or it is free and its own
    true cell is free. Returns ``(accuracy, number of classified cells)``.
    """
    iy, ix = np.nonzero(classified >= 0)
    if len(ix) == 0:
        return float("nan"), 0
    centres = grid_spec.cell_to_world(np.column_stack([ix, iy]))
    tc = truth_spec.world_to_cell(centres)
    inside = truth_spec.contains(tc)
    pad = np.pad(truth, 1)
    near = np.zeros_like(pad)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            near |= np.roll(np.roll(pad, dy, 0), dx, 1)
    tx = np.clip(tc[:, 0], 0, truth_spec.width - 1)
    ty = np.clip(tc[:, 1], 0, truth_spec.height - 1)
    true_occ = np.where(inside, truth[ty, tx], False)
    near_occ = np.where(inside, near[ty + 1, tx + 1], False)
    cls = classified[iy, ix]
    correct = np.where(cls == 1, near_occ, ~true_occ)
    return float(correct.mean()), int(len(ix))
