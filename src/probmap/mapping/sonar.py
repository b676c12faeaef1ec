"""Wide-beam (sonar cone) range sensors: simulation, the log-odds baseline, a corridor world.

A cone of full opening angle ``opening`` is sampled by ``subrays`` rays evenly spread over the
opening (:func:`probmap.mapping.map_mapping.cone_offsets`). A sonar reports the range to the
nearest obstacle anywhere in its cone, i.e. the smallest range over the sub-rays. This is the
sensor of Probabilistic Robotics Figure 9.8 and section 9.4: in a corridor with an open door a
cone wider than the door sees the door frame, and the log-odds map (Table 9.1 with the
inverse model applied to the whole cone) closes the door, while the MAP map keeps it open.

The log-odds baseline, :func:`~probmap.mapping.map_mapping.cone_log_odds_grid`, lives beside
the MAP mapper that starts from it and is re-exported here (``sonar`` imports ``map_mapping``,
never the other way round).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap.grid.raycast import cast_rays
from probmap.grid.spec import GridSpec

# the log-odds baseline lives beside the MAP mapper it initialises; re-exported here
from probmap.mapping.map_mapping import cone_log_odds_grid, cone_offsets

__all__ = ["SonarWorld", "cone_log_odds_grid", "corridor_with_door", "simulate_cone_ranges"]


def simulate_cone_ranges(
    truth: ArrayLike,
    spec: GridSpec,
    poses: ArrayLike,
    angles: ArrayLike,
    max_range: float,
    *,
    opening: float,
    subrays: int,
    noise: float = 0.0,
    seed: int | None = 0,
) -> NDArray[np.float64]:
    """Cone readings on a true map: the nearest obstacle over the sub-rays, plus noise.

    Parameters
    ----------
    truth : array_like of bool, shape (H, W)
        True occupied cells.
    spec : GridSpec
        Geometry of ``truth``.
    poses : array_like, shape (S, 3)
        Sensor poses ``(x, y, theta)`` (m, rad).
    angles : array_like, shape (B,)
        Cone axis angles in the sensor frame, radians.
    max_range : float
        Maximum range (m): no obstacle within it gives exactly ``max_range``.
    opening, subrays
        Full opening angle (rad) and the number of sub-rays sampling it.
    noise : float
        Standard deviation (m) of Gaussian noise added to readings below ``max_range``.
    seed : int or None
        Seed of the noise.

    Returns
    -------
    ndarray, shape (S, B)
    """
    P = np.atleast_2d(np.asarray(poses, dtype=np.float64))
    A = np.asarray(angles, dtype=np.float64).ravel()
    offs = cone_offsets(opening, subrays)
    sub = (A[:, None] + offs[None, :]).ravel()
    r = cast_rays(truth, spec, P, sub, max_range).reshape(P.shape[0], A.shape[0], offs.shape[0])
    z = r.min(axis=2)
    if noise > 0:
        rng = np.random.default_rng(seed)
        hit = z < max_range
        z[hit] = np.clip(z[hit] + rng.normal(0.0, noise, int(hit.sum())), 1e-3, max_range - 1e-6)
    return z


@dataclass(frozen=True, eq=False)
class SonarWorld:
    """A true map and the cone readings a sonar ring took in it (see :func:`corridor_with_door`).

    Attributes
    ----------
    truth : ndarray of bool, shape (H, W)
    spec : GridSpec
    poses : ndarray, shape (S, 3)
        Sensor poses (m, rad).
    ranges : ndarray, shape (S, B)
        Cone readings (m).
    angles : ndarray, shape (B,)
        Cone axes in the sensor frame (rad).
    max_range, opening : float
        Metres and radians.
    subrays : int
    """

    truth: NDArray[np.bool_]
    spec: GridSpec
    poses: NDArray[np.float64]
    ranges: NDArray[np.float64]
    angles: NDArray[np.float64]
    max_range: float
    opening: float
    subrays: int


def corridor_with_door(
    *,
    resolution: float = 0.1,
    length: float = 8.0,
    width: float = 1.6,
    door: float = 0.8,
    opening: float = math.radians(30.0),
    subrays: int = 15,
    n_sonars: int = 8,
    step: float = 0.1,
    max_range: float = 5.0,
    noise: float = 0.02,
    seed: int = 0,
) -> SonarWorld:
    """A straight corridor with an open door into a room, mapped by a ring of sonars.

    The corridor runs along x from 0 to ``length`` with walls 2 cells thick at
    ``y = 0`` and ``y = width``; a door ``door`` metres wide in the upper wall, centred on the
    corridor, opens into a 3 m deep room. The robot drives along the corridor's centre line
    with ``n_sonars`` cones evenly spaced around it.
    """
    r = resolution
    t = 2
    wall_lo = 1.0
    wall_hi = wall_lo + width
    room_top = wall_hi + 3.0
    spec = GridSpec(r, (-1.0, 0.0), (round((room_top + 1.0) / r), round((length + 2.0) / r)))
    occ = np.zeros(spec.shape, dtype=bool)

    def iy(y: float) -> int:
        return int(round(y / r))

    def ix(x: float) -> int:
        return int(round((x + 1.0) / r))

    occ[iy(wall_lo) - t : iy(wall_lo), ix(-0.5) : ix(length + 0.5)] = True  # lower wall
    occ[iy(wall_hi) : iy(wall_hi) + t, ix(-0.5) : ix(length + 0.5)] = True  # upper wall
    occ[iy(wall_lo) - t : iy(room_top) + t, ix(-0.5) - t : ix(-0.5)] = True  # corridor ends
    occ[iy(wall_lo) - t : iy(room_top) + t, ix(length + 0.5) : ix(length + 0.5) + t] = True
    occ[iy(room_top) : iy(room_top) + t, ix(-0.5) : ix(length + 0.5)] = True  # room's far wall
    mid = 0.5 * length
    occ[iy(wall_hi) : iy(wall_hi) + t, ix(mid - door / 2) : ix(mid + door / 2)] = False  # door
    xs = np.arange(0.5, length - 0.5 + 1e-9, step)
    poses = np.column_stack([xs, np.full_like(xs, wall_lo + width / 2), np.zeros_like(xs)])
    angles = np.arange(n_sonars) * (2 * math.pi / n_sonars)
    ranges = simulate_cone_ranges(
        occ, spec, poses, angles, max_range, opening=opening, subrays=subrays, noise=noise,
        seed=seed,
    )  # fmt: skip
    return SonarWorld(
        occ, spec, poses, ranges, np.asarray(angles, dtype=np.float64), max_range, opening, subrays
    )
