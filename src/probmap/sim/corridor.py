"""A simulated long loop of featureless corridors: the degenerate case of scan matching.

A rectangular ring corridor (``width`` metres wide) around a solid block, with straight walls
and nothing on them. With a sensor range shorter than the corridor, a scan in the middle of a
long side sees two parallel walls only: the scan constrains the pose across the corridor and
in heading, not along it. A matcher that takes the best pose of a flat score (or is pulled
back onto the known part of the map) slides along the corridor at every update, and the map
of the loop comes out too short; grid SLAM tests use it to check the degeneracy guard.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from probmap.grid.spec import GridSpec
from probmap.sim.laser import SimulatedLaserWorld, drive_route, interpolate_route, walled_box

__all__ = ["corridor_plan", "simulate_corridor_loop"]


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
