"""A simulated floor of identical offices: the case where loop closure is fooled by look-alikes.

A straight corridor with a row of identical offices on each side, each office open to the
corridor through a door. A scan in the corridor sees the same doors and walls every
``office`` metres, so a scan matched against the map of an earlier pass fits equally well one
office further on: with odometry that has drifted by about half an office, the best match can
be the wrong one, and a closure that accepts it folds the map by a whole office. The robot
drives the corridor out and back, so the way back revisits every office.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from probmap.grid.spec import GridSpec
from probmap.sim.laser import SimulatedLaserWorld, drive_route, interpolate_route, walled_box

__all__ = ["office_floor_plan", "simulate_office_floor"]


def office_floor_plan(
    offices: int = 10,
    office: float = 4.0,
    depth: float = 4.0,
    corridor: float = 2.0,
    door: float = 1.0,
    resolution: float = 0.05,
) -> tuple[NDArray[np.bool_], GridSpec]:
    """The true occupancy (H, W) of a corridor ``offices * office`` metres long and
    ``corridor`` wide, with ``offices`` identical offices (``office`` x ``depth`` metres, a door
    of ``door`` metres at the same place in each) on either side, and its GridSpec (origin
    (0, 0), the corridor along +x at ``depth < y < depth + corridor``)."""
    if not (offices >= 2 and office > door > 0 and depth > 0 and corridor > 0):
        raise ValueError("need offices >= 2 and office > door > 0, depth, corridor > 0")
    occ, spec, t = walled_box(offices * office, 2 * depth + corridor, resolution)
    y0, y1 = round(depth / resolution), round((depth + corridor) / resolution)
    occ[y0 : y0 + t, :] = True  # the corridor's two walls
    occ[y1 - t : y1, :] = True
    for k in range(offices):
        x = round(k * office / resolution)
        occ[:, x : x + t] = True  # the wall between two offices (and the corridor's ends)
        occ[y0 + t : y1 - t, x : x + t] = k == 0  # ... but not across the corridor
        d0 = round((k * office + (office - door) / 2) / resolution)
        d1 = d0 + round(door / resolution)
        occ[y0 : y0 + t, d0:d1] = False  # the doors
        occ[y1 - t : y1, d0:d1] = False
    return occ, spec


def simulate_office_floor(
    *,
    seed: int = 0,
    offices: int = 10,
    office: float = 4.0,
    step: float = 0.1,
    n_beams: int = 181,
    fov: float = 2 * np.pi * 270 / 360,
    max_range: float = 8.0,
    range_noise: float = 0.01,
    pose_noise: tuple[float, float] = (0.03, 0.01),
) -> SimulatedLaserWorld:
    """A robot driving the corridor of :func:`office_floor_plan` to its far end and back.

    Parameters
    ----------
    seed : int
        Seed of the random generator.
    offices, office : int, float
        Offices per side and their width (metres).
    step : float
        Distance between scans, metres.
    n_beams, fov, max_range, range_noise : int, float, float, float
        Laser: beams over ``fov`` radians, maximum range and range noise (metres).
    pose_noise : tuple of float
        Odometry drift per metre travelled: standard deviations (metres, radians).

    Returns
    -------
    SimulatedLaserWorld
        Scans every ``step`` metres, timestamps 0.1 s apart.
    """
    rng = np.random.default_rng(seed)
    depth, corridor = 4.0, 2.0
    truth, spec = office_floor_plan(offices, office, depth, corridor)
    y = depth + corridor / 2
    far = offices * office - 1.0
    way = np.array([[1.0, y], [far, y], [far - 0.01, y + 0.3], [1.0, y + 0.3]])
    angles = np.linspace(-fov / 2, fov / 2, n_beams)
    return drive_route(
        truth, spec, interpolate_route(way, step), rng, angles, max_range=max_range,
        range_noise=range_noise, pose_noise=pose_noise, heading_noise=0.02,
    )  # fmt: skip
