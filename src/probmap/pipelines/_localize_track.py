"""Tracking helpers of :func:`probmap.pipelines.localize.localize_scans`: the pose it reports
(the particle cloud's estimate refined against the map), the scan match that moves a cloud the
odometry misled, and random poses near where a filter lost track.

The reported pose
-----------------
The particle cloud's mean jitters from update to update by about the cloud's own spread: with
a few thousand particles and a tempered likelihood (``LocalizeConfig.independent_beams``) that
is centimetres, and a metric over consecutive poses (the relation metric, Kuemmerle et al.
2009) sees all of it. The map says more than the cloud's mean does. :func:`refine_pose` takes
the cloud as a Gaussian prior ``N(mu, Sigma)`` (its weighted mean and covariance) and the
scan's endpoints as measurements of the distance to the nearest obstacle, and finds the maximum
a posteriori pose by Gauss-Newton,

``min_x  sum_i rho(d(q_i(x))^2 / sigma^2) + (x - mu)^T Sigma^-1 (x - mu)``

with ``d`` the map's distance field (bilinear between cell centres), ``q_i(x)`` the endpoint
of beam ``i`` seen from pose ``x`` and ``rho`` a truncated quadratic (an endpoint farther than
``outlier`` from any obstacle counts for nothing: people, doors, the map's own gaps). Where the
scan constrains the pose (a room, a corner) the optimum follows the scan; along a featureless
corridor the scan says nothing and the prior keeps the cloud's mean, so the reported pose never
slides where the particles would not. The particles are not moved: the cloud and its spread
stay what the filter made of them.

The refined pose is reported only where it is clearly better evidence than the mean: the
cloud is tight (``max_spread``), most of the beams end near an obstacle there
(``min_inliers``), and it lies within the cloud (a Mahalanobis distance of at most
``max_mahalanobis`` under the cloud's covariance, widened by ``floor``). Otherwise the run
reports the mean, as before.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap.geometry.se2 import between, compose, inverse, wrap_angle
from probmap.models.grid_map import GridGeometry

__all__ = [
    "NearbyFreeSpace",
    "RefineConfig",
    "RefinedPose",
    "follow_scan",
    "laser_offset_of",
    "match_times",
    "odometry_track",
    "refine_pose",
]


@dataclass(frozen=True)
class RefineConfig:
    """Parameters of :func:`refine_pose`.

    Parameters
    ----------
    sigma : float
        Standard deviation (m) of an endpoint's distance to the map's obstacles at the right
        pose (sensor noise and the map's cell size).
    outlier : float
        Endpoints farther than this (m) from any obstacle carry no weight.
    iterations : int
        Gauss-Newton iterations at most.
    min_inliers : float
        The refined pose is used only when at least this fraction of the beams with a return
        end within ``outlier`` of an obstacle there.
    max_mahalanobis : float
        ... and when it lies within this Mahalanobis distance of the cloud's mean, under the
        cloud's covariance plus ``floor``.
    floor : (float, float)
        Standard deviations (m, rad) added to the cloud's: a cloud that has collapsed to a
        point still lets the scan move the estimate by about this much.
    max_spread : float
        The cloud's mean is reported as it is where the cloud's largest positional standard
        deviation exceeds this (m): a cloud stretched along a corridor of look-alike doors
        knows it does not know where along it the robot is, and the scan's best fit there
        would snap to whichever door of the map fits (``tests/filters/test_mcl_corridor.py``:
        0.72 m off with 0.15, as the mean's 0.50; Intel: 96 % of the updates refined).
    """

    sigma: float = 0.05
    outlier: float = 0.2
    iterations: int = 8
    min_inliers: float = 0.6
    max_mahalanobis: float = 5.0
    floor: tuple[float, float] = (0.02, math.radians(1.0))
    max_spread: float = 0.1


@dataclass(frozen=True)
class RefinedPose:
    """The outcome of :func:`refine_pose`.

    Attributes
    ----------
    pose : (3,) ndarray
        The pose to report (robot, map frame; m, rad): the refined one when ``used``, else the
        cloud's mean.
    used : bool
        Whether the refined pose passed the checks.
    inliers : float
        The fraction of the beams with a return that end within ``outlier`` of an obstacle,
        seen from the refined pose.
    mahalanobis : float
        The refined pose's Mahalanobis distance from the cloud's mean.
    """

    pose: NDArray[np.float64]
    used: bool
    inliers: float
    mahalanobis: float


def refine_pose(
    lf: Any,
    mean: NDArray[np.float64],
    covariance: NDArray[np.float64],
    lx: NDArray[np.float64],
    ly: NDArray[np.float64],
    config: RefineConfig | None = None,
) -> RefinedPose:
    """The maximum a posteriori pose of the scan against the map, with the particle cloud as
    prior (see the module's text).

    Parameters
    ----------
    lf : LikelihoodField
        The map's likelihood field (:class:`~probmap.models.likelihood_field.LikelihoodField`):
        its ``distance`` field and ``frame``.
    mean : (3,) ndarray
        The cloud's estimate (robot pose, map frame; m, rad): the prior's mean and the start.
    covariance : (3, 3) ndarray
        The cloud's covariance (m^2, m rad, rad^2).
    lx, ly : (B,) ndarray
        The endpoints of the beams with a return in the robot frame (m), as
        ``LikelihoodField.endpoints`` gives them (valid ones only).
    config : RefineConfig, optional

    Returns
    -------
    RefinedPose

    Examples
    --------
    >>> import numpy as np
    >>> from types import SimpleNamespace
    >>> from probmap.models.likelihood_field import LikelihoodField
    >>> occ = np.zeros((60, 60), bool); occ[:, 40] = True; occ[10, :] = True  # a corner
    >>> lf = LikelihoodField(SimpleNamespace(resolution=0.05, origin=(0.0, 0.0),
    ...     shape=(60, 60)), occ, max_range=5.0)
    >>> a = np.linspace(-1.5, 0.0, 40)  # beams from (1.0, 1.5): the wall x = 2.025, y = 0.525
    >>> r = np.minimum(1.025 / np.cos(a), 0.975 / np.abs(np.sin(a) + 1e-12))
    >>> lx, ly = r * np.cos(a), r * np.sin(a)
    >>> out = refine_pose(lf, np.array([1.04, 1.47, 0.0]), np.diag([0.05**2, 0.05**2, 0.02**2]),
    ...     lx, ly)
    >>> out.used, np.round(out.pose[:2], 2).tolist()
    (True, [1.0, 1.5])
    """
    cfg = config or RefineConfig()
    mu = np.ascontiguousarray(np.asarray(mean, dtype=np.float64).reshape(3))
    bx = np.ascontiguousarray(lx, dtype=np.float64)
    by = np.ascontiguousarray(ly, dtype=np.float64)
    cov = np.asarray(covariance, dtype=np.float64).reshape(3, 3)
    half = 0.5 * float(cov[0, 0] - cov[1, 1])  # the largest eigenvalue of the xy block:
    top = 0.5 * float(cov[0, 0] + cov[1, 1]) + math.hypot(half, float(cov[0, 1]))
    wide = not top <= cfg.max_spread**2
    if bx.size < 3 or wide:  # a cloud stretched along a corridor: its mean, not a look-alike
        return RefinedPose(mu.copy(), False, 0.0, 0.0)
    f = lf.frame
    x0, y0, res = float(f.x0), float(f.y0), float(f.resolution)
    dist = lf.distance
    far = float(lf.max_distance)
    fl = np.array([cfg.floor[0] ** 2, cfg.floor[0] ** 2, cfg.floor[1] ** 2])
    try:
        prior = np.ascontiguousarray(np.linalg.inv(cov + np.diag(fl)))
    except np.linalg.LinAlgError:
        return RefinedPose(mu.copy(), False, 0.0, math.inf)
    from probmap.pipelines import _localize_track_kernels as _k

    x = np.empty(3)
    n_in, q = _k.refine(
        dist, x0, y0, res, far, cfg.outlier, cfg.sigma**2, bx, by, mu, prior,
        int(cfg.iterations), x,
    )  # fmt: skip
    fraction = n_in / bx.size
    maha = math.sqrt(max(float(q), 0.0))
    used = fraction >= cfg.min_inliers and maha <= cfg.max_mahalanobis
    return RefinedPose(x if used else mu.copy(), used, fraction, maha)


class NearbyFreeSpace:
    """Random poses over the free space within a disc around where the filter lost track (see
    ``localize_scans``), by rejection; the disc starts at 2 m and doubles every ``per``
    updates, and once it holds the whole map (or a draw finds no free cell) ``fallback``, the
    sampler over all free space, draws."""

    def __init__(self, spec: GridGeometry, free: NDArray[np.bool_], fallback: Any) -> None:
        self.free = free
        self.res = float(spec.resolution)
        self.x0, self.y0 = (float(v) for v in spec.origin)
        h, w = free.shape
        self.size = math.hypot(h * self.res, w * self.res)
        self.fallback = fallback
        self.center = np.zeros(2)
        self.updates = 0

    def start(self, pose: NDArray[np.float64]) -> None:
        self.center = np.array(pose[:2], dtype=np.float64)
        self.updates = 0

    def widen(self, per: int) -> NearbyFreeSpace:
        self.radius = 2.0 * 2.0 ** (self.updates / per)
        self.updates += 1
        return self

    def sample(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        if self.radius >= self.size:
            return np.asarray(self.fallback.sample(n, rng))
        h, w = self.free.shape
        got: list[NDArray[np.float64]] = []
        count = 0
        for _ in range(20):
            m = 4 * n
            rad = self.radius * np.sqrt(rng.uniform(size=m))
            ang = rng.uniform(-np.pi, np.pi, size=m)
            x = self.center[0] + rad * np.cos(ang)
            y = self.center[1] + rad * np.sin(ang)
            ix = np.floor((x - self.x0) / self.res).astype(np.int64)
            iy = np.floor((y - self.y0) / self.res).astype(np.int64)
            ok = (ix >= 0) & (iy >= 0) & (ix < w) & (iy < h)
            ok[ok] = self.free[iy[ok], ix[ok]]
            got.append(np.column_stack([x[ok], y[ok], rng.uniform(-np.pi, np.pi, int(ok.sum()))]))
            count += int(ok.sum())
            if count >= n:
                return np.concatenate(got)[:n]
        return np.asarray(self.fallback.sample(n, rng))


def follow_scan(
    mcl: Any,
    lf: Any,
    pose: NDArray[np.float64],
    ranges: NDArray[np.float64],
    angles: NDArray[np.float64],
    mount: NDArray[np.float64],
    cfg: Any,
) -> bool:
    """Match the scan against the map around the estimate ``pose`` (robot, map frame); when a
    pose inside the window (not on its edge) fits better by more than ``cfg.match_gain``
    log-likelihood per beam, and fits the map as a converged filter must (``converged_matched``
    of the beams near an obstacle), move the particles
    within ``2 match_window`` of the estimate as the estimate moves to it (odometry that
    contradicts the laser). Returns whether it moved them."""
    window = float(cfg.match_window or 0.0)
    lx, ly, ok = lf.endpoints(ranges, angles, mount)
    best, gain = lf.local_search(pose, lx[ok], ly[ok], (window, cfg.match_turn))
    d = best - pose
    turn = abs(math.remainder(float(d[2]), 2 * math.pi))
    # an optimum on the window's edge is no local optimum: a look-alike further off (Intel, in
    # a map from its corrected log, where people hide the walls)
    edge = max(abs(d[0]), abs(d[1])) > 0.99 * window or turn > 0.99 * cfg.match_turn > 0
    if not gain > cfg.match_gain or edge:
        return False
    # and the scan must fit there as a converged filter's does: where it fits no pose well
    # (people, a part of the map that is off) a better pose is no better evidence
    if lf.matched_fraction(best, ranges, angles, mount, 2 * cfg.sigma_hit) < cfg.converged_matched:
        return False
    step = compose(best, inverse(pose))
    pts = mcl.particles
    near = np.hypot(pts[:, 0] - pose[0], pts[:, 1] - pose[1]) <= 2.0 * window
    pts[near] = compose(step, pts[near])
    return True


def odometry_track(
    odometry: NDArray[np.float64],
    scan_index: NDArray[np.int64],
    poses: NDArray[np.float64],
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """The robot's pose at every scan from the first update to the last, by the odometry
    between the updates.

    A filter updates every ``update_distance`` of motion; between two updates ``i`` and
    ``i + 1`` (scans ``k_i < k_{i+1}``) the odometry says how the robot moved. Scan ``j``
    between them gets the pose the odometry gives from update ``i`` forward,
    ``A = compose(poses_i, between(odometry_{k_i}, odometry_j))``, blended with the one it
    gives from update ``i + 1`` backward, ``B``, by ``alpha = (j - k_i) / (k_{i+1} - k_i)``:
    exact at both updates, continuous, and local (a blend of two poses a few centimetres
    apart, not of two map-to-odometry corrections, which a small turn would swing by metres far
    from the origin). Where the odometry logs a reversing as forward driving between two
    updates, ``A`` and ``B`` err in opposite directions and the blend follows the filter.
    A straight line between the updates instead cuts every curve (Intel: a relation error of
    0.040 m for the SLAM trajectory itself, sampled at the updates; 0.017 m by the odometry).

    Parameters
    ----------
    odometry : (S, 3) ndarray
        The odometry pose of every scan (m, rad).
    scan_index : (T,) int ndarray
        The scan of each update, increasing.
    poses : (T, 3) ndarray
        The estimate at each update (robot, map frame; m, rad).

    Returns
    -------
    scans : (M,) int ndarray
        ``scan_index[0]`` to ``scan_index[-1]``, every scan.
    track : (M, 3) ndarray
        The robot's pose at each (map frame; m, rad).

    Examples
    --------
    >>> import numpy as np
    >>> odo = np.column_stack([np.arange(5) * 0.1, np.zeros(5), np.zeros(5)])
    >>> scans, track = odometry_track(odo, np.array([0, 4]), np.array([[1.0, 0, 0], [1.4, 0, 0]]))
    >>> scans.tolist(), np.round(track[:, 0], 2).tolist()
    ([0, 1, 2, 3, 4], [1.0, 1.1, 1.2, 1.3, 1.4])
    """
    idx = np.asarray(scan_index, dtype=np.int64)
    est = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    odo = np.asarray(odometry, dtype=np.float64)
    if idx.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    if np.any(np.diff(idx) <= 0):
        raise ValueError("scan_index must increase")
    scans = np.arange(idx[0], idx[-1] + 1)
    if idx.size == 1:
        return scans, est.copy()
    i = np.clip(np.searchsorted(idx, scans, side="right") - 1, 0, idx.size - 2)
    k1, k2 = idx[i], idx[i + 1]
    fwd = np.asarray(compose(est[i], between(odo[k1], odo[scans]))).reshape(-1, 3)
    back = np.asarray(compose(est[i + 1], between(odo[k2], odo[scans]))).reshape(-1, 3)
    alpha = ((scans - k1) / (k2 - k1))[:, None]
    d = back - fwd
    d[:, 2] = np.remainder(d[:, 2] + math.pi, 2 * math.pi) - math.pi
    track = fwd + alpha * d
    track[:, 2] = np.remainder(track[:, 2] + math.pi, 2 * math.pi) - math.pi
    return scans, track


def turned_against_odometry(
    turns: list[tuple[int, float]],
    scan: int,
    pose: NDArray[np.float64],
    odometry: NDArray[np.float64],
    prev: tuple[int, NDArray[np.float64]] | None,
    window: int,
) -> tuple[int, float]:
    """How far the estimate has turned against the odometry over the last ``window`` updates.

    A tracking filter corrects the odometry's heading by a few degrees over a few metres; an
    estimate that turns tens of degrees more (or less) than the odometry within a few seconds
    has been pulled to a wrong place (Freiburg 079, in the map of its own ``slam grid``: 30-55
    deg within 5 s at t = 249 s, where the scans see what the map lacks and the likelihood
    field fits them better to a turned pose whose beams cross walls). The odometry's heading
    stays right even where it logs reversing as forward driving.

    Parameters
    ----------
    turns : list of (int, float)
        Per update, its scan and the estimate's turn less the odometry's since the update
        before (rad); updated in place (this update appended, the list cut to ``window``,
        cleared where ``prev`` is None).
    scan : int
        This update's scan.
    pose : (3,) ndarray
        This update's estimate (m, rad).
    odometry : (S, 3) ndarray
        The odometry of every scan.
    prev : (int, (3,) ndarray) or None
        The previous update's scan and estimate, when it had converged.
    window : int
        Updates summed.

    Returns
    -------
    first : int
        The scan of the first update summed (this one's when none).
    turned : float
        The absolute sum (rad).
    """
    if prev is None:
        turns.clear()
        return scan, 0.0
    k1, p1 = prev
    est = math.remainder(float(pose[2] - p1[2]), 2 * math.pi)
    odo = math.remainder(float(odometry[scan, 2] - odometry[k1, 2]), 2 * math.pi)
    turns.append((scan, est - odo))
    del turns[:-window]
    return turns[0][0], abs(sum(d for _, d in turns))


def laser_offset_of(
    robot_poses: ArrayLike,
    laser_poses: ArrayLike,
    *,
    tolerance: tuple[float, float] = (0.01, 0.01),
) -> NDArray[np.float64] | None:
    """The laser's mounting pose in the robot frame, ``between(robot_pose, laser_pose)``, from
    poses logged together (a CARMEN ``ROBOTLASER1`` or ``FLASER`` line has both; the Freiburg
    hospital's laser sits 0.22 m ahead of the robot).

    Parameters
    ----------
    robot_poses, laser_poses : (S, 3) array_like
        Robot and laser poses at the same scans, one frame (m, rad).
    tolerance : (float, float)
        Largest deviation (m, rad) of a scan's offset from the median for the poses to
        describe one rigid mounting.

    Returns
    -------
    (3,) ndarray or None
        The median offset ``(x, y, theta)`` (m, m, rad); None when the offsets differ by more
        than ``tolerance`` (laser poses corrected by SLAM next to raw odometry, say), so that
        they describe no mounting.
    """
    robot = np.asarray(robot_poses, dtype=np.float64).reshape(-1, 3)
    laser = np.asarray(laser_poses, dtype=np.float64).reshape(-1, 3)
    if robot.shape != laser.shape or robot.shape[0] == 0:
        raise ValueError(
            f"need robot and laser poses (S, 3) alike, got {robot.shape}, {laser.shape}"
        )
    d = np.asarray(between(robot, laser)).reshape(-1, 3)
    off = np.median(d, axis=0)
    off[2] = float(wrap_angle(off[2] + np.median(wrap_angle(d[:, 2] - off[2]))))
    far = np.hypot(d[:, 0] - off[0], d[:, 1] - off[1])
    turn = np.abs(wrap_angle(d[:, 2] - off[2]))
    if float(far.max()) > tolerance[0] or float(turn.max()) > tolerance[1]:
        return None
    return off


def match_times(
    times: ArrayLike, ref_times: ArrayLike, max_dt: float = 0.02
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Pairs ``(i, j)`` with ``|times[i] - ref_times[j]| <= max_dt``, nearest ``i`` per ``j``.

    ``times`` must be sorted ascending.
    """
    t = np.asarray(times, dtype=np.float64)
    rt = np.asarray(ref_times, dtype=np.float64)
    if t.size == 0 or rt.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    i = (
        np.clip(np.searchsorted(t, rt), 1, max(t.size - 1, 1))
        if t.size > 1
        else np.zeros(rt.size, dtype=np.int64)
    )
    if t.size > 1:
        i = np.where(np.abs(t[i - 1] - rt) < np.abs(t[i] - rt), i - 1, i)
    ok = np.abs(t[i] - rt) <= max_dt
    return i[ok].astype(np.int64), np.flatnonzero(ok).astype(np.int64)
