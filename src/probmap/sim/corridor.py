"""A simulated long loop of featureless corridors: the degenerate case of scan matching.

A rectangular ring corridor (``width`` metres wide) around a solid block, with straight walls
and nothing on them. With a sensor range shorter than the corridor, a scan in the middle of a
long side sees two parallel walls only: the scan constrains the pose across the corridor and
in heading, not along it. A matcher that takes the best pose of a flat score (or is pulled
back onto the known part of the map) slides along the corridor at every update, and the map
of the loop comes out too short; grid SLAM tests use it to check the degeneracy guard.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from probmap.grid.spec import GridSpec
from probmap.sim.laser import SimulatedLaserWorld, drive_route, interpolate_route, walled_box

__all__ = ["DoorCorridor", "corridor_plan", "simulate_corridor_loop", "simulate_door_corridor"]


def corridor_plan(
    length: float = 40.0, height: float = 10.0, width: float = 2.0, resolution: float = 0.05
) -> tuple[NDArray[np.bool_], GridSpec]:
    """The true occupancy (H, W) of a ring corridor of ``width`` metres inside a
    ``length`` x ``height`` metre rectangle, and its GridSpec (origin (0, 0))."""
    if not (length > 2 * width + 1 and height > 2 * width + 1 and width > 0):
        raise ValueError(f"need length, height > 2 width + 1 m, got {length}, {height}, {width}")
    occ, spec, _ = walled_box(length, height, resolution)
    i0, i1 = round(width / resolution), round((length - width) / resolution)
    j0, j1 = round(width / resolution), round((height - width) / resolution)
    occ[j0:j1, i0:i1] = True
    return occ, spec


def simulate_corridor_loop(
    *,
    seed: int = 0,
    length: float = 40.0,
    height: float = 10.0,
    width: float = 2.0,
    step: float = 0.1,
    laps: float = 1.1,
    n_beams: int = 181,
    max_range: float = 8.0,
    range_noise: float = 0.01,
    pose_noise: tuple[float, float] = (0.03, 0.03),
) -> SimulatedLaserWorld:
    """A robot driving ``laps`` times counter-clockwise along the centre line of
    :func:`corridor_plan` (a 2 (length + height) - 4 width metre loop).

    Parameters
    ----------
    seed : int
        Seed of the random generator.
    length, height, width : float
        Outer size of the ring and corridor width, metres.
    step : float
        Distance between scans, metres.
    laps : float
        Laps driven (> 1 revisits the start: the loop closure).
    n_beams, max_range, range_noise : int, float, float
        Laser: beams over 180 degrees, maximum range (metres) and range noise (metres).
    pose_noise : tuple of float
        Odometry drift per metre travelled: standard deviations (metres, radians).

    Returns
    -------
    SimulatedLaserWorld
        Scans every ``step`` metres, timestamps 0.1 s apart.
    """
    rng = np.random.default_rng(seed)
    truth, spec = corridor_plan(length, height, width)
    c = width / 2
    way = np.array([[c, c], [length - c, c], [length - c, height - c], [c, height - c], [c, c]])
    lap = interpolate_route(way, step)
    extra = int(len(lap) * (laps - 1.0))
    xy = np.concatenate([lap, lap[1 : 1 + extra]]) if extra > 0 else lap
    angles = np.linspace(-np.pi / 2, np.pi / 2, n_beams)
    return drive_route(
        truth, spec, xy, rng, angles, max_range=max_range, range_noise=range_noise,
        pose_noise=pose_noise, heading_noise=0.03,
    )  # fmt: skip


@dataclass(frozen=True)
class DoorCorridor:
    """A straight corridor with doors, and a map of it whose doors are a little off.

    Attributes
    ----------
    world : SimulatedLaserWorld
        The drive: true poses, drifting odometry, scans of the true corridor.
    map_occupied : (H, W) bool ndarray
        The map the robot localizes in: the corridor with every door moved along it by a
        random amount (the errors of a map built by SLAM), on ``world.spec``.
    """

    world: SimulatedLaserWorld
    map_occupied: NDArray[np.bool_]


def _door_plan(
    length: float, width: float, doors: list[tuple[float, int]], resolution: float
) -> tuple[NDArray[np.bool_], GridSpec]:
    depth, door = 0.3, 1.0  # door recesses: 0.3 m deep, 1 m wide
    occ, spec, t = walled_box(length, width + 2 * depth, resolution)
    j0, j1 = round(depth / resolution), round((width + depth) / resolution)
    occ[:j0, :] = True
    occ[j1:, :] = True
    for x, side in doors:
        i0, i1 = round((x - door / 2) / resolution), round((x + door / 2) / resolution)
        rows = slice(t, j0) if side == 0 else slice(j1, occ.shape[0] - t)
        occ[rows, max(i0, t) : i1] = False
    return occ, spec


def simulate_door_corridor(
    *,
    seed: int = 0,
    length: float = 60.0,
    width: float = 2.4,
    door_spacing: float = 4.0,
    map_error: float = 0.3,
    step: float = 0.05,
    n_beams: int = 181,
    max_range: float = 8.0,
) -> DoorCorridor:
    """A robot driving the length of a corridor with a door every ``door_spacing`` metres on
    both sides, and a map in which each door is moved along the corridor by
    ``N(0, map_error^2)`` metres.

    The doors look alike and the laser (``max_range`` < ``length``) never sees both ends: only
    odometry tells where along the corridor the robot is, and the map's doors pull a filter that
    trusts every beam to wherever they fit the scan best.

    Parameters
    ----------
    seed : int
        Seeds the map's door errors, the heading wobble, the range noise and the odometry drift.
    length, width : float
        Corridor length and width (m).
    door_spacing : float
        Distance between doors along each wall (m).
    map_error : float
        Standard deviation (m) of a door's displacement in the map.
    step : float
        Distance between scans (m), timestamps 0.1 s apart.
    n_beams, max_range : int, float
        Laser: beams over 180 degrees, maximum range (m); range noise 0.02 m.

    Returns
    -------
    DoorCorridor
    """
    rng = np.random.default_rng(seed)
    resolution = 0.05
    doors = [(float(x), s) for x in np.arange(3.0, length - 2.0, door_spacing) for s in (0, 1)]
    truth, spec = _door_plan(length, width, doors, resolution)
    moved = [(x + float(rng.normal(0.0, map_error)), s) for x, s in doors]
    map_occ, _ = _door_plan(length, width, moved, resolution)
    y = 0.3 + width / 2
    xy = interpolate_route(np.array([[2.0, y], [length - 2.0, y]]), step)
    angles = np.linspace(-np.pi / 2, np.pi / 2, n_beams)
    world = drive_route(
        truth, spec, xy, rng, angles, max_range=max_range, range_noise=0.02,
        pose_noise=(0.03, 0.03), heading_noise=0.01,
    )  # fmt: skip
    return DoorCorridor(world, map_occ)
