"""A simulated laser robot: the steps every laser world of :mod:`probmap.sim` shares.

A world (a floor plan, a ring corridor, a labelled building) is a true occupancy map and a
route through it. These functions turn the route into what a robot would record, in the order
every simulator of the package draws its random numbers:

1. :func:`interpolate_route`: a pose every ``step`` metres along the waypoints;
2. :func:`poses_along`: each pose heads to the next one, with a little Gaussian heading wobble
   so that scans see more of the walls;
3. :func:`noisy_ranges`: ranges ray-cast on the true map (:func:`probmap.grid.raycast.cast_rays`)
   with Gaussian range noise and, optionally, dropped readings;
4. :func:`drift_odometry`: odometry integrated from noisy relative motions.

Everything takes an explicit :class:`numpy.random.Generator`, so that equal seeds give equal
worlds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap.grid.spec import GridSpec

__all__ = [
    "drive_route",
    "walled_box",
    "SimulatedLaserWorld",
    "drift_odometry",
    "interpolate_route",
    "noisy_ranges",
    "poses_along",
]


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


def interpolate_route(waypoints: ArrayLike, step: float) -> NDArray[np.float64]:
    """Points every ``step`` metres (or a little less) along a polyline, its ends included.

    Each segment is split into ``ceil(length / step)`` equal parts (at least one).

    Parameters
    ----------
    waypoints : array_like, shape (N, 2)
        Corners of the route (m).
    step : float
        Largest distance between consecutive points (m).

    Returns
    -------
    ndarray, shape (M, 2)

    Examples
    --------
    >>> interpolate_route([[0.0, 0.0], [1.0, 0.0], [1.0, 0.5]], 0.5).tolist()
    [[0.0, 0.0], [0.5, 0.0], [1.0, 0.0], [1.0, 0.5]]
    """
    way = np.asarray(waypoints, dtype=np.float64)
    pts = [way[0]]
    for a, b in zip(way[:-1], way[1:], strict=True):
        n = max(1, int(np.ceil(float(np.hypot(*(b - a))) / step)))
        pts += [a + (b - a) * k / n for k in range(1, n + 1)]
    return np.asarray(pts)


def poses_along(
    xy: NDArray[np.float64], rng: np.random.Generator, wobble: float
) -> NDArray[np.float64]:
    """Poses at the points ``xy``, each heading to the next (the last keeps its heading).

    Parameters
    ----------
    xy : ndarray, shape (S, 2)
        Positions (m), e.g. from :func:`interpolate_route`.
    rng : numpy.random.Generator
        Draws the wobble (``S`` normal samples).
    wobble : float
        Standard deviation (rad) of Gaussian noise added to every heading.

    Returns
    -------
    ndarray, shape (S, 3)
        ``(x, y, theta)``.
    """
    heading = np.arctan2(np.diff(xy[:, 1]), np.diff(xy[:, 0]))
    poses = np.column_stack([xy, np.concatenate([heading, heading[-1:]])])
    poses[:, 2] += rng.normal(0.0, wobble, len(poses))
    return poses


def noisy_ranges(
    true_ranges: NDArray[np.float64],
    max_range: float,
    rng: np.random.Generator,
    noise: float,
    dropout: float = 0.0,
) -> NDArray[np.float64]:
    """Measured ranges: the true ones with Gaussian noise, and readings dropped at random.

    A reading with a return (``true < max_range``) gets ``N(0, noise^2)`` added and is kept in
    ``[1 mm, max_range)``, so noise never turns a return into a max-range reading; a reading
    without a return is exactly ``max_range``.

    Parameters
    ----------
    true_ranges : ndarray, shape (S, B)
        Ranges cast on the true map (m), ``max_range`` for no return.
    max_range : float
        Sensor maximum range (m).
    rng : numpy.random.Generator
        Draws the noise (``S * B`` normal samples), then the dropouts (``S * B`` uniform
        samples, only when ``dropout > 0``).
    noise : float
        Standard deviation of the range noise (m).
    dropout : float
        Probability that a reading is NaN (a dropped reading).

    Returns
    -------
    ndarray, shape (S, B)
    """
    hit = true_ranges < max_range
    ranges = np.where(hit, true_ranges + rng.normal(0.0, noise, true_ranges.shape), max_range)
    ranges = np.where(hit, np.clip(ranges, 1e-3, max_range - 1e-6), ranges)
    if dropout > 0:
        ranges[rng.random(ranges.shape) < dropout] = np.nan
    return ranges


def drift_odometry(
    poses: NDArray[np.float64], rng: np.random.Generator, noise: tuple[float, float]
) -> NDArray[np.float64]:
    """Odometry that drifts: the true relative motions with noise, integrated from the start.

    Each motion between consecutive true poses is taken in the robot frame of the first
    (forward, lateral, turn); its forward part and its turn get Gaussian noise whose standard
    deviation grows with the distance travelled, and the noisy motions are chained from the
    first true pose (the odometry motion model of Probabilistic Robotics section 5.4, in its
    simplest form).

    Parameters
    ----------
    poses : ndarray, shape (S, 3)
        True poses ``(x, y, theta)`` (m, rad).
    rng : numpy.random.Generator
        Draws two normal samples per motion: forward, then turn.
    noise : tuple of float
        Drift per metre travelled: standard deviations of the forward motion (m/m) and of the
        turn (rad/m).

    Returns
    -------
    ndarray, shape (S, 3)
        Odometry poses; the first equals ``poses[0]``.
    """
    odo = poses.copy()
    for k in range(1, len(poses)):
        dx, dy = poses[k, :2] - poses[k - 1, :2]
        c, s = math.cos(poses[k - 1, 2]), math.sin(poses[k - 1, 2])
        fwd, lat = c * dx + s * dy, -s * dx + c * dy
        dth = poses[k, 2] - poses[k - 1, 2]
        dist = float(np.hypot(dx, dy))
        fwd += rng.normal(0, noise[0] * dist + 1e-12)
        dth += rng.normal(0, noise[1] * dist + 1e-12)
        c, s = math.cos(odo[k - 1, 2]), math.sin(odo[k - 1, 2])
        odo[k] = odo[k - 1] + np.array([c * fwd - s * lat, s * fwd + c * lat, dth])
    return odo


def walled_box(
    length: float, height: float, resolution: float
) -> tuple[NDArray[np.bool_], GridSpec, int]:
    """An empty ``length`` x ``height`` metre rectangle with walls 0.15 m thick along its
    border: the occupancy (H, W), its GridSpec (origin (0, 0)) and the wall thickness in cells,
    for the floor plans to draw their inner walls in."""
    shape = (round(height / resolution), round(length / resolution))
    spec = GridSpec(resolution, (0.0, 0.0), shape)
    occ = np.zeros(spec.shape, dtype=bool)
    t = max(1, round(0.15 / resolution))  # wall thickness in cells
    occ[:t, :] = True
    occ[-t:, :] = True
    occ[:, :t] = True
    occ[:, -t:] = True
    return occ, spec, t


def drive_route(
    truth: NDArray[np.bool_],
    spec: GridSpec,
    xy: ArrayLike,
    rng: np.random.Generator,
    angles: NDArray[np.float64],
    *,
    max_range: float,
    range_noise: float,
    pose_noise: tuple[float, float],
    heading_noise: float,
    period: float = 0.1,
) -> SimulatedLaserWorld:
    """A robot on the route ``xy`` (M, 2) in ``truth``: poses along it (heading noise
    ``heading_noise`` rad), noisy scans, drifting odometry and a scan every ``period``
    seconds, drawn from ``rng`` in that order."""
    from probmap.grid.raycast import cast_rays

    poses = poses_along(np.asarray(xy, dtype=np.float64), rng, heading_noise)
    ranges = noisy_ranges(
        cast_rays(truth, spec, poses, angles, max_range), max_range, rng, range_noise
    )
    odo = drift_odometry(poses, rng, pose_noise)
    times = np.arange(len(poses), dtype=np.float64) * period
    return SimulatedLaserWorld(truth, spec, poses, odo, ranges, angles, float(max_range), times)
