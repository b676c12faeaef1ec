"""Scan matching against an occupancy grid: correlative search refined by Gauss-Newton.

A scan's endpoints are scored on a smooth *match field* derived from the map, ``M(q) =
exp(-d(q)^2 / (2 sigma^2))`` with ``d`` the distance to the nearest occupied cell (the
likelihood field of Probabilistic Robotics Table 6.3 without its random component). The matcher

1. searches a box of poses around the initial guess on the nearest-cell score (correlative
   matching, Olson 2009), which gives a wide basin of convergence;
2. refines the best pose by Gauss-Newton on ``sum_i (1 - M(q_i))^2`` with the bilinear field and
   its analytic gradient (as Kohlbrecher et al. 2011, Hector SLAM);
3. returns the pose with a covariance ``sigma_r^2 (J^T J)^-1`` from the final normal equations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._checks import require_at_least, require_nonnegative_finite, require_positive_finite
from probmap.geometry.se2 import wrap_angle
from probmap.grid.spec import GridSpec


@dataclass(frozen=True)
class MatcherConfig:
    """Parameters of :func:`match_scan`.

    Parameters
    ----------
    sigma : float
        Width of the match field in metres (distance at which ``M`` falls to ``e^-1/2``).
    linear_window, linear_step : float
        Half-width and step of the correlative search in x and y, metres.
    angular_window, angular_step : float
        Half-width and step of the correlative search in heading, radians.
    iterations : int
        Maximum Gauss-Newton iterations.
    usable_range : float
        Endpoints farther than this (metres) are not used for matching.
    beam_skip : int
        Use every ``beam_skip``-th beam.
    """

    sigma: float = 0.05
    linear_window: float = 0.2
    linear_step: float = 0.05
    angular_window: float = 0.1
    angular_step: float = 0.01
    iterations: int = 10
    usable_range: float = 15.0
    beam_skip: int = 1

    def __post_init__(self) -> None:
        for name in ("sigma", "linear_step", "angular_step", "usable_range"):
            require_positive_finite(name, getattr(self, name))
        for name in ("linear_window", "angular_window"):
            require_nonnegative_finite(name, getattr(self, name))
        require_at_least("iterations", self.iterations, 0)
        require_at_least("beam_skip", self.beam_skip, 1)


def laser_slam_matcher() -> MatcherConfig:
    """The matcher both laser SLAM methods start from: the RBPF uses it as it is
    (:class:`~probmap.slam.laser.rbpf.RbpfConfig`), submap graph SLAM widens its window."""
    return MatcherConfig(
        sigma=0.05,
        linear_window=0.1,
        linear_step=0.025,
        angular_window=0.05,
        angular_step=0.0125,
        iterations=8,
        usable_range=30.0,
        beam_skip=1,
    )


@dataclass(frozen=True, eq=False)
class MatchField:
    """A match field ``M`` on a grid: ``values[iy, ix]`` in [0, 1] at the cell centres.

    An unnormalised score ``exp(-d^2 / 2 sigma^2)`` of the distance ``d`` to the nearest
    obstacle, sampled bilinearly (Gauss-Newton needs its gradient) or at the nearest cell (the
    correlative and branch-and-bound searches). It is not the likelihood field model of
    :class:`probmap.models.likelihood_field.LikelihoodField`, a normalised density mixed with
    a uniform term and looked up per cell as a log-likelihood for Monte Carlo localization:
    the two differ in their values and in what consumes them, so each keeps its own home.

    Attributes
    ----------
    values : ndarray, shape (H, W), float64, C-contiguous
    origin : tuple of float
        World position (metres) of the lower-left corner of cell (0, 0).
    resolution : float
        Cell side, metres.
    """

    values: NDArray[np.float64]
    origin: tuple[float, float]
    resolution: float

    def __post_init__(self) -> None:
        v = self.values
        if not isinstance(v, np.ndarray) or v.ndim != 2 or v.dtype != np.float64:
            raise ValueError("values must be a 2-D float64 array")
        if not v.flags.c_contiguous:
            raise ValueError("values must be C-contiguous")
        if not (math.isfinite(self.resolution) and self.resolution > 0):
            raise ValueError(f"resolution must be > 0 m, got {self.resolution}")

    @classmethod
    def from_occupied(cls, occupied: ArrayLike, spec: GridSpec, sigma: float = 0.05) -> MatchField:
        """The field of a boolean occupancy image ``occupied[iy, ix]`` laid out by ``spec``."""
        from scipy.ndimage import distance_transform_edt

        occ = np.asarray(occupied, dtype=bool)
        if occ.shape != spec.shape:
            raise ValueError(f"occupied has shape {occ.shape}, spec says {spec.shape}")
        if not sigma > 0:
            raise ValueError(f"sigma must be > 0 m, got {sigma}")
        if occ.any():
            d = distance_transform_edt(~occ) * spec.resolution
            values = np.exp(-0.5 * (d / sigma) ** 2)
        else:
            values = np.zeros(occ.shape)
        return cls(np.ascontiguousarray(values), spec.origin, spec.resolution)

    @classmethod
    def from_grid(cls, grid: object, sigma: float = 0.05, threshold: float = 0.5) -> MatchField:
        """The field of an :class:`~probmap.grid.occupancy.OccupancyGrid` (or any object with
        ``probability()`` and ``spec``): cells with ``p > threshold`` are occupied."""
        p = np.asarray(grid.probability())  # type: ignore[attr-defined]
        return cls.from_occupied(p > threshold, grid.spec, sigma)  # type: ignore[attr-defined]


@dataclass(frozen=True)
class MatchResult:
    """The outcome of :func:`match_scan`.

    Attributes
    ----------
    pose : ndarray, shape (3,)
        Matched sensor pose ``(x, y, theta)`` in the map frame.
    covariance : ndarray, shape (3, 3)
        Its covariance (m^2, m rad, rad^2).
    score : float
        Mean field value of the endpoints at ``pose`` (1 = every endpoint on an obstacle).
    points : int
        Endpoints used.
    iterations : int
        Gauss-Newton iterations taken.
    """

    pose: NDArray[np.float64]
    covariance: NDArray[np.float64]
    score: float
    points: int
    iterations: int


def scan_points(
    ranges: ArrayLike,
    angles: ArrayLike,
    max_range: float,
    usable_range: float = math.inf,
    beam_skip: int = 1,
) -> NDArray[np.float64]:
    """Endpoints (N, 2) in the sensor frame of the valid beams (``0 < r < min(max_range,
    usable_range)``), every ``beam_skip``-th beam."""
    r = np.asarray(ranges, dtype=np.float64)
    a = np.asarray(angles, dtype=np.float64)
    if r.ndim != 1 or a.shape != r.shape:
        raise ValueError(f"ranges {r.shape} and angles {a.shape} must be 1-D of equal length")
    r = r[::beam_skip]
    a = a[::beam_skip]
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(r) & (r > 0) & (r < max_range) & (r < usable_range)
    return np.ascontiguousarray(np.column_stack([r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok])]))


def _check(field: MatchField, points: ArrayLike, pose: ArrayLike) -> tuple[NDArray, NDArray]:
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"points must have shape (N, 2), got {pts.shape}")
    if not np.isfinite(pts).all():
        raise ValueError("points must be finite")
    p = np.asarray(pose, dtype=np.float64)
    if p.shape != (3,) or not np.isfinite(p).all():
        raise ValueError(f"pose must be 3 finite numbers (x, y, theta), got {p.tolist()}")
    return pts, p


def point_terms(field: MatchField, points: ArrayLike, pose: ArrayLike) -> NDArray[np.float64]:
    """Per endpoint, ``(M, dM/dx, dM/dy, dM/dtheta)`` at ``pose``, shape (N, 4)."""
    from probmap.slam.laser import _match_kernels as K

    pts, p = _check(field, points, pose)
    out = np.empty((pts.shape[0], 4))
    ox, oy = field.origin
    K.point_terms(field.values, ox, oy, field.resolution, pts, p[0], p[1], p[2], out)
    return out


def normal_equations(
    field: MatchField, points: ArrayLike, pose: ArrayLike
) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """Score ``sum M``, gradient ``J^T r`` (3,) and Gauss-Newton Hessian ``J^T J`` (3, 3) of
    ``sum_i r_i^2 / 2`` with ``r_i = 1 - M(q_i)``."""
    from probmap.slam.laser import _match_kernels as K

    pts, p = _check(field, points, pose)
    g = np.zeros(3)
    H = np.zeros((3, 3))
    ox, oy = field.origin
    score, _ = K.gauss_newton_terms(
        field.values, ox, oy, field.resolution, pts, p[0], p[1], p[2], g, H
    )
    return float(score), g, H


def score_scan(field: MatchField, points: ArrayLike, pose: ArrayLike) -> float:
    """Nearest-cell score ``sum_i M(cell(q_i))`` of the endpoints at ``pose``."""
    from probmap.slam.laser import _match_kernels as K

    pts, p = _check(field, points, pose)
    ox, oy = field.origin
    return float(K.nearest_score(field.values, ox, oy, field.resolution, pts, p[0], p[1], p[2]))


def correlative_search(
    field: MatchField, points: ArrayLike, initial: ArrayLike, config: MatcherConfig
) -> tuple[NDArray[np.float64], float]:
    """Best pose of the nearest-cell score on the search box of ``config`` around ``initial``.

    Returns the pose (3,) and its score. Of equal scores the first visited wins (heading,
    then x, then y, each from the most negative offset).
    """
    from probmap.slam.laser import _match_kernels as K

    pts, p = _check(field, points, initial)
    out = np.empty(4)
    ox, oy = field.origin
    K.correlative_search(
        field.values,
        ox,
        oy,
        field.resolution,
        pts,
        p[0],
        p[1],
        p[2],
        config.linear_window,
        config.linear_step,
        config.angular_window,
        config.angular_step,
        out,
    )
    return out[:3].copy(), float(out[3])


def correlative_distribution(
    field: MatchField,
    points: ArrayLike,
    initial: ArrayLike,
    config: MatcherConfig,
    temperature: float = 1.0,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float]:
    """The search box of ``config`` around ``initial`` as a distribution over poses.

    Each pose of the box gets the weight ``exp((S - S_max) / temperature)`` (``S`` the
    nearest-cell score); returns the weighted mean pose (3,), the weighted covariance (3, 3) of
    the poses (m^2, m rad, rad^2), the best pose (3,) as :func:`correlative_search` finds it,
    and ``S_max`` (Olson 2009, "Real-time correlative scan
    matching", sec. IV). Unlike the best pose, the mean does not depend on the order of the
    search when the score is flat (a featureless corridor), and the covariance is large along
    such directions.
    """
    from probmap.slam.laser import _match_kernels as K

    pts, p = _check(field, points, initial)
    if not (math.isfinite(temperature) and temperature > 0):
        raise ValueError(f"temperature must be > 0, got {temperature}")
    out = np.empty(13)
    ox, oy = field.origin
    K.correlative_moments(
        field.values, ox, oy, field.resolution, pts, p[0], p[1], p[2], config.linear_window,
        config.linear_step, config.angular_window, config.angular_step, float(temperature), out,
    )  # fmt: skip
    mean = p + out[1:4]
    mean[2] = float(wrap_angle(mean[2]))
    xx, xy, xt, yy, yt, tt = out[4:10]
    cov = np.array([[xx, xy, xt], [xy, yy, yt], [xt, yt, tt]])
    return mean, cov, out[10:13].copy(), float(out[0])


def refine(
    field: MatchField,
    points: ArrayLike,
    initial: ArrayLike,
    iterations: int = 10,
    max_step: tuple[float, float] = (0.05, 0.02),
) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
    """Gauss-Newton refinement of ``initial`` on the bilinear field.

    Each step solves ``(J^T J + mu I) delta = -J^T r`` (a small ``mu`` keeps it solvable on
    degenerate geometry, e.g. a corridor), is shortened to at most ``max_step`` (metres,
    radians) so that it stays in the basin the coarse search found, and is kept only if it
    lowers ``sum r^2``.

    Returns the pose (3,), its covariance (3, 3) and the iterations taken.
    """
    from probmap.slam.laser import _match_kernels as K

    pts, p = _check(field, points, initial)
    ox, oy = field.origin
    pose = np.empty(3)
    H = np.zeros((3, 3))
    it, sq = K.refine_pose(
        field.values, ox, oy, field.resolution, pts, p[0], p[1], p[2], int(iterations),
        float(max_step[0]), float(max_step[1]), pose, H,
    )  # fmt: skip
    p = pose
    n = max(pts.shape[0] - 3, 1)
    var_r = max(sq / n, 1e-6)
    info = H + 1e-9 * np.eye(3)
    try:
        cov = var_r * np.linalg.inv(info)
    except np.linalg.LinAlgError:  # pragma: no cover - guarded by the regulariser
        cov = np.eye(3) * 1e6
    cov = 0.5 * (cov + cov.T)
    p = p.copy()
    p[2] = float(wrap_angle(p[2]))
    return p, cov, it


def match_scan(
    field: MatchField,
    points: ArrayLike,
    initial: ArrayLike,
    config: MatcherConfig | None = None,
) -> MatchResult:
    """Match scan endpoints (sensor frame, (N, 2)) against ``field`` starting at ``initial``.

    Parameters
    ----------
    field : MatchField
        The map's match field.
    points : array_like, shape (N, 2)
        Endpoints in the sensor frame (see :func:`scan_points`).
    initial : array_like, shape (3,)
        Initial guess of the sensor pose in the map frame.
    config : MatcherConfig, optional

    Returns
    -------
    MatchResult

    Raises
    ------
    ValueError
        If the scan has fewer than 3 endpoints or inputs have the wrong shape.
    """
    cfg = config or MatcherConfig()
    pts, p = _check(field, points, initial)
    if pts.shape[0] < 3:
        raise ValueError(f"a scan needs at least 3 valid endpoints to match, got {pts.shape[0]}")
    best, _ = correlative_search(field, pts, p, cfg)
    pose, cov, it = refine(field, pts, best, cfg.iterations, (cfg.linear_step, cfg.angular_step))
    score, _, _ = normal_equations(field, pts, pose)
    return MatchResult(pose, cov, score / pts.shape[0], int(pts.shape[0]), it)
