"""Grid-based FastSLAM from raw laser logs: a Rao-Blackwellized particle filter with an
improved proposal from scan matching (Probabilistic Robotics 13.10; Grisetti, Stachniss and
Burgard, "Improved techniques for grid mapping with Rao-Blackwellized particle filters",
IEEE T-RO 23(1), 2007).

Per processed scan (the robot has moved ``linear_update`` metres or turned ``angular_update``
radians since the last one), for every particle:

1. predict the pose from the odometry increment;
2. match the scan against the particle's own map (:func:`~probmap.slam.laser.scan_matching.
   match_scan`), which finds the mode of the observation likelihood; by default guarded
   against degenerate geometry (:meth:`RbpfSlam._match_guarded`: no correction from a flat
   score along a featureless corridor);
3. evaluate ``tau_j = p(z | m, x_j) p(x_j | x_{t-1}, u)`` on poses ``x_j`` around the mode, fit
   a Gaussian to them (Grisetti 2007, eqs. 15-16) and draw the new pose from it; the weight is
   multiplied by ``eta = sum_j tau_j`` (eq. 18);
4. integrate the scan into the particle's map (Table 9.1).

When the match fails (too few endpoints on the map) the particle falls back to the odometry
motion model (Table 5.6) and the plain likelihood weight. Particles are resampled (Table 4.4)
only when the effective sample size falls below half the particle count. Maps are shared
between particles tile by tile with copy on write (:mod:`probmap.slam.laser._tiles`), and
trajectories are a tree of nodes shared by descendants.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._checks import require_at_least, require_nonnegative_finite, require_positive_finite
from probmap.geometry.se2 import between, compose, inverse, wrap_angle
from probmap.grid.occupancy import OccupancyGrid
from probmap.slam.laser.scan_matching import (
    MatcherConfig,
    MatchField,
    laser_slam_matcher,
    match_scan,
    scan_points,
)


@dataclass(frozen=True)
class RbpfConfig:
    """Parameters of :class:`RbpfSlam` (defaults serve indoor logs such as Intel).

    Parameters
    ----------
    particles : int
        Number of particles.
    resolution : float
        Map cell side, metres.
    linear_update, angular_update : float
        Process a scan once the robot has moved this far (metres) or turned this much (rad).
    matcher : MatcherConfig
        The scan matcher.
    field_radius : int
        Cells beyond which the match field is 0.
    likelihood_sigma : float
        Standard deviation (metres) of the endpoint likelihood used for the proposal and the
        weights; wider than the matcher's field to temper over-confident likelihoods.
    likelihood_skip : int
        Every ``likelihood_skip``-th endpoint enters the likelihood.
    weight_gain : float
        Log-likelihood increments are divided by this before they enter the weights
        (GMapping's observation gain, smoothing the resampling).
    proposal_delta : tuple of float
        Offsets ``(metres, radians)`` of the 3 x 3 x 3 sample poses around the mode.
    odometry_noise : tuple of float
        ``(srr, srt, str, stt)``: translation noise per metre and per radian, rotation noise
        per metre and per radian (standard deviations, GMapping's convention).
    min_score : float
        Least mean match score (0..1) for the match to be trusted.
    p_hit, p_miss, clamp : float
        The inverse sensor model (probabilities) and log-odds clamping bounds.
    max_clear_range : float
        Max-range readings clear space up to this distance (metres); 0 = never.
    tile : int
        Map tile side in cells (copy-on-write granularity).
    seed : int
        Seed of the random generator.
    degeneracy_guard : bool
        Let the match correct the odometry only along the directions the scan constrains:
        endpoints on never-observed cells are left out of the match, and along a featureless
        corridor the odometry is kept (see :meth:`RbpfSlam._match_guarded`). Off when the log
        has no odometry (there is nothing else to keep).
    match_temperature : float
        Score difference (in matched endpoints) that lowers a pose's weight in the correlative
        distribution by ``e`` (used by the guard).
    degenerate_sd : float
        Standard deviation (metres) of the correlative distribution along a direction beyond
        which the match is taken as unconstrained there (a flat score over the search window of
        half-width ``w`` gives ``w / sqrt(3)``; ties between neighbouring steps about half
        that).
    known_fraction : float
        The guard leaves out endpoints on never-observed cells only when at least this
        fraction of them lands on observed cells (in new rooms all are kept).
    """

    particles: int = 30
    resolution: float = 0.05
    linear_update: float = 0.5
    angular_update: float = 0.25
    matcher: MatcherConfig = field(default_factory=laser_slam_matcher)
    field_radius: int = 3
    likelihood_sigma: float = 0.075
    likelihood_skip: int = 2
    weight_gain: float = 10.0
    proposal_delta: tuple[float, float] = (0.01, 0.005)
    odometry_noise: tuple[float, float, float, float] = (0.1, 0.2, 0.1, 0.2)
    min_score: float = 0.25
    p_hit: float = 0.7
    p_miss: float = 0.4
    clamp: tuple[float, float] = (0.12, 0.97)
    max_clear_range: float = 0.0
    tile: int = 32
    seed: int = 0
    degeneracy_guard: bool = True
    match_temperature: float = 1.0
    degenerate_sd: float = 0.04
    known_fraction: float = 0.8

    def __post_init__(self) -> None:
        require_at_least("particles", self.particles, 1)
        positive = ("resolution", "likelihood_sigma", "weight_gain", "match_temperature",
                    "degenerate_sd")  # fmt: skip
        for name in positive:
            require_positive_finite(name, getattr(self, name))
        for name in ("linear_update", "angular_update", "max_clear_range", "min_score"):
            require_nonnegative_finite(name, getattr(self, name))
        if not 0.0 <= self.known_fraction <= 1.0:
            raise ValueError(f"known_fraction must be in [0, 1], got {self.known_fraction}")
        if self.field_radius < 1 or self.likelihood_skip < 1:
            raise ValueError("field_radius and likelihood_skip must be >= 1")
        if not 0.0 < self.p_miss < 0.5 < self.p_hit < 1.0:
            raise ValueError(f"need 0 < p_miss < 0.5 < p_hit < 1, got {self.p_miss}, {self.p_hit}")
        if not 0.0 < self.clamp[0] < 0.5 < self.clamp[1] < 1.0:
            raise ValueError(f"clamp must satisfy 0 < lo < 0.5 < hi < 1, got {self.clamp}")
        if min(self.odometry_noise) < 0 or min(self.proposal_delta) <= 0:
            raise ValueError("odometry_noise must be >= 0 and proposal_delta > 0")


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


@dataclass(frozen=True, eq=False)
class RbpfResult:
    """The best particle's map and trajectory, and what the filter did.

    Attributes
    ----------
    grid : OccupancyGrid
        The best particle's map, cropped to the observed cells.
    times : ndarray, shape (S,)
        Timestamps of every scan of the input (seconds).
    poses : ndarray, shape (S, 3)
        Best particle's robot poses at those times; between processed scans the odometry
        increments are composed onto the last processed pose.
    processed : int
        Scans processed by the filter.
    resamples : int
        Resampling steps.
    neff : ndarray, shape (processed,)
        Effective sample size after each processed scan (before resampling).
    failed_matches : int
        Particle updates that fell back to the motion model.
    map_bytes : int
        Largest memory held by the shared map tiles, bytes.
    seconds : float
        Wall time of the filter.
    """

    grid: OccupancyGrid
    times: NDArray[np.float64]
    poses: NDArray[np.float64]
    processed: int
    resamples: int
    neff: NDArray[np.float64]
    failed_matches: int
    map_bytes: int
    seconds: float


class RbpfSlam:
    """Rao-Blackwellized particle filter for grid SLAM with the improved proposal.

    Parameters
    ----------
    config : RbpfConfig
    angles : array_like, shape (B,)
        Beam angles in the sensor frame (radians).
    max_range : float
        Sensor maximum range (metres); readings at or beyond it are "no return".
    sample : bool
        Draw poses from the proposal (True) or take its mean (False: with one particle this is
        scan-to-map matching odometry).

    Notes
    -----
    The filter estimates the *sensor* pose; the caller composes the mounting offset.
    """

    def __init__(
        self, config: RbpfConfig, angles: ArrayLike, max_range: float, *, sample: bool = True
    ) -> None:
        from probmap.slam.laser._tiles import TiledMaps

        self.config = config
        self.angles = np.ascontiguousarray(angles, dtype=np.float64)
        if self.angles.ndim != 1 or not np.isfinite(self.angles).all():
            raise ValueError("angles must be a finite 1-D array")
        if not max_range > 0:
            raise ValueError(f"max_range must be > 0 m, got {max_range}")
        self.max_range = float(max_range)
        self.sample = sample
        n = config.particles
        self.rng = np.random.default_rng(config.seed)
        self.maps = TiledMaps(n, config.resolution, config.tile)
        self.poses = np.zeros((n, 3))
        self.log_w = np.zeros(n)
        # trajectory tree: node -> (pose, parent, scan index)
        self._node_pose: list[NDArray[np.float64]] = []
        self._node_parent: list[int] = []
        self._node_scan: list[int] = []
        self.nodes = np.full(n, -1, dtype=np.int64)
        self.last_odometry: NDArray[np.float64] | None = None
        self.processed = 0
        self.resamples = 0
        self.failed = 0
        self.degenerate = 0
        self.neff: list[float] = []
        self.map_bytes = 0
        self._l_hit = _logit(config.p_hit)
        self._l_miss = _logit(config.p_miss)
        self._l_min = _logit(config.clamp[0])
        self._l_max = _logit(config.clamp[1])
        d, a = config.proposal_delta
        g = np.array(np.meshgrid([-d, 0, d], [-d, 0, d], [-a, 0, a], indexing="ij"))
        self._offsets = np.ascontiguousarray(g.reshape(3, -1).T)

    # ------------------------------------------------------------------ helpers
    def _add_node(self, k: int, pose: NDArray[np.float64], scan: int) -> None:
        self._node_pose.append(pose.copy())
        self._node_parent.append(int(self.nodes[k]))
        self._node_scan.append(scan)
        self.nodes[k] = len(self._node_pose) - 1

    def _scan_angles(self, ranges: NDArray, angles: ArrayLike | None) -> NDArray[np.float64]:
        """The beam angles of one scan: ``angles`` when given (a log whose scans change
        geometry), else the filter's; checked against the scan's length."""
        a = self.angles if angles is None else np.ascontiguousarray(angles, dtype=np.float64)
        if a.shape != ranges.shape:
            raise ValueError(f"the scan has {ranges.shape[0]} ranges but {a.shape[0]} beam angles")
        if angles is not None and not np.isfinite(a).all():
            raise ValueError("angles must be finite")
        return a

    def _window(
        self, pose: NDArray[np.float64], ranges: NDArray[np.float64], angles: NDArray
    ) -> tuple:
        """Tile range covering the scan from ``pose`` with the matcher's search margin."""
        cfg = self.config
        m = cfg.matcher
        clear = cfg.max_clear_range
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(ranges) & (ranges > 0)
            r = np.where(ranges < self.max_range, ranges, clear)[ok]
        a = angles[ok] + pose[2]
        xs = np.concatenate([[pose[0]], pose[0] + r * np.cos(a)])
        ys = np.concatenate([[pose[1]], pose[1] + r * np.sin(a)])
        margin = m.linear_window + m.angular_window * float(r.max(initial=0.0)) + 0.5
        box = (xs.min() - margin, ys.min() - margin, xs.max() + margin, ys.max() + margin)
        return self.maps.tile_range(box)

    def _integrate(
        self,
        k: int,
        tr: tuple,
        lo: NDArray[np.float32],
        pose: NDArray,
        ranges: NDArray,
        angles: NDArray,
    ) -> None:
        """Integrate the scan into particle ``k``'s map window and write it back (Table 9.1)."""
        from probmap.slam.laser import _match_kernels as K

        cfg = self.config
        stamp = np.zeros(lo.shape, dtype=np.uint8)
        ox, oy = self.maps.window_origin(tr[0], tr[1])
        T = cfg.tile
        touched = np.zeros((lo.shape[0] // T, lo.shape[1] // T), dtype=np.uint8)
        K.integrate_window(
            lo, stamp, ox, oy, cfg.resolution, pose[0], pose[1], pose[2], ranges, angles,
            self.max_range, cfg.max_clear_range, self._l_hit, self._l_miss, self._l_min,
            self._l_max, T, touched,
        )  # fmt: skip
        self.maps.scatter(k, tr, lo, touched)

    def _motion_sigmas(self, u: NDArray) -> tuple[float, float]:
        """Standard deviations (metres, radians) of the odometry prediction for the increment
        ``u``, growing with the distance and rotation travelled (GMapping's model)."""
        srr, srt, s_r, stt = self.config.odometry_noise
        dist = math.hypot(u[0], u[1])
        rot = abs(float(wrap_angle(u[2])))
        return srr * dist + srt * rot + 0.01, s_r * dist + stt * rot + 0.01

    def _motion_log_prior(self, predicted: NDArray, poses: NDArray, u: NDArray) -> NDArray:
        """Log of a Gaussian ``p(x | x_{t-1}, u)`` around the odometry prediction (robot
        frame of the prediction), standard deviations from :meth:`_motion_sigmas`."""
        sxy, sth = self._motion_sigmas(u)
        d = between(predicted, poses)
        return -0.5 * ((d[:, 0] ** 2 + d[:, 1] ** 2) / sxy**2 + wrap_angle(d[:, 2]) ** 2 / sth**2)

    def _log_likelihoods(self, fld: MatchField, pts: NDArray, poses: NDArray) -> NDArray:
        from probmap.slam.laser import _match_kernels as K

        cfg = self.config
        out = np.empty(poses.shape[0])
        sub = np.ascontiguousarray(pts[:: cfg.likelihood_skip])
        floor = -0.5 * (cfg.field_radius * cfg.resolution / cfg.matcher.sigma) ** 2
        ox, oy = fld.origin
        K.log_likelihoods(
            fld.values, ox, oy, fld.resolution, sub, np.ascontiguousarray(poses), floor, out
        )
        # the field is exp(-d^2 / 2 sigma^2): rescale to the likelihood's own sigma
        return out * (cfg.matcher.sigma / cfg.likelihood_sigma) ** 2

    # ------------------------------------------------------------------ filter steps
    def initialize(
        self, scan: int, ranges: ArrayLike, odometry: ArrayLike, angles: ArrayLike | None = None
    ) -> None:
        """Start every particle at the first scan's odometry pose with that scan in its map
        (``angles``: as for :meth:`update`)."""
        r = np.ascontiguousarray(ranges, dtype=np.float64)
        a = self._scan_angles(r, angles)
        pose = np.asarray(odometry, dtype=np.float64).copy()
        self.poses[:] = pose
        tr = self._window(pose, r, a)
        lo = self.maps.gather(0, tr)
        self._integrate(0, tr, lo, pose, r, a)
        self.maps.resample(np.zeros(self.config.particles, dtype=np.int64))
        for k in range(self.config.particles):
            self._add_node(k, pose, scan)
        self.last_odometry = pose.copy()
        self.processed = 1

    def moved_enough(self, odometry: ArrayLike) -> bool:
        """Whether the odometry moved ``linear_update`` or turned ``angular_update`` since the
        last processed scan."""
        assert self.last_odometry is not None
        u = between(self.last_odometry, np.asarray(odometry, dtype=np.float64))
        return bool(
            math.hypot(u[0], u[1]) >= self.config.linear_update
            or abs(float(wrap_angle(u[2]))) >= self.config.angular_update
        )

    def update(
        self, scan: int, ranges: ArrayLike, odometry: ArrayLike, angles: ArrayLike | None = None
    ) -> None:
        """Process one scan: predict, match, sample from the improved proposal, weight,
        integrate, and resample when ``N_eff < N / 2``.

        ``angles`` (radians, the same length as ``ranges``) are this scan's beam angles when
        they differ from the filter's (a log whose scans change between 180 and 181 beams).
        """
        from probmap.filters.resampling import (
            effective_sample_size,
            log_normalize,
            low_variance_resample,
        )

        if self.last_odometry is None:
            self.initialize(scan, ranges, odometry, angles)
            return
        cfg = self.config
        r = np.ascontiguousarray(ranges, dtype=np.float64)
        ang = self._scan_angles(r, angles)
        odo = np.asarray(odometry, dtype=np.float64)
        u = between(self.last_odometry, odo)
        m = cfg.matcher
        pts = scan_points(r, ang, self.max_range, m.usable_range, m.beam_skip)
        for k in range(cfg.particles):
            predicted = compose(self.poses[k], u)
            tr = self._window(predicted, r, ang)
            lo = self.maps.gather(k, tr)
            fld = self._field(lo, tr)
            use = self._known_points(lo, fld, pts, predicted) if cfg.degeneracy_guard else pts
            new, dlw = self._propose(fld, use, predicted, u)
            self.poses[k] = new
            self.log_w[k] += dlw / cfg.weight_gain
            self._integrate(k, tr, lo, new, r, ang)
            self._add_node(k, new, scan)
        self.last_odometry = odo.copy()
        self.processed += 1
        w, _ = log_normalize(self.log_w)
        neff = effective_sample_size(w)
        self.neff.append(neff)
        self.map_bytes = max(self.map_bytes, self.maps.nbytes())
        if neff < cfg.particles / 2:
            idx = low_variance_resample(w, self.rng)
            self.poses = self.poses[idx]
            self.nodes = self.nodes[idx]
            self.maps.resample(idx)
            self.log_w = np.zeros(cfg.particles)
            self.resamples += 1
        else:
            self.log_w = np.log(np.maximum(w, 1e-300))

    def _field(self, lo: NDArray[np.float32], tr: tuple) -> MatchField:
        from probmap.slam.laser import _match_kernels as K

        cfg = self.config
        values = np.empty(lo.shape)
        inv = 0.5 * (cfg.resolution / cfg.matcher.sigma) ** 2
        K.splat_field(lo, 0.0, cfg.field_radius, inv, values)
        return MatchField(values, self.maps.window_origin(tr[0], tr[1]), cfg.resolution)

    def _known_points(
        self, lo: NDArray[np.float32], fld: MatchField, pts: NDArray, predicted: NDArray
    ) -> NDArray[np.float64]:
        """The endpoints that land, seen from the predicted pose, on cells observed before
        (all endpoints when fewer than ``known_fraction`` of them do).

        Endpoints on never-observed cells carry no information about the pose (the likelihood
        field is uniform there, Table 6.3), yet on the map's field they pull the match back
        onto the known map: the new stretch of a corridor wall ahead would drag every match
        backwards along the corridor.
        """
        c, s = math.cos(predicted[2]), math.sin(predicted[2])
        qx = predicted[0] + c * pts[:, 0] - s * pts[:, 1]
        qy = predicted[1] + s * pts[:, 0] + c * pts[:, 1]
        ix = np.floor((qx - fld.origin[0]) / fld.resolution).astype(np.int64)
        iy = np.floor((qy - fld.origin[1]) / fld.resolution).astype(np.int64)
        h, w = lo.shape
        inside = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
        known = np.zeros(len(pts), dtype=bool)
        known[inside] = lo[iy[inside], ix[inside]] != 0.0
        if known.sum() < self.config.known_fraction * len(pts):
            return pts  # much new ground (a new room): too few would be left; keep them all
        return np.ascontiguousarray(pts[known])

    def _match_guarded(
        self, fld: MatchField, pts: NDArray, predicted: NDArray, u: NDArray
    ) -> NDArray[np.float64] | None:
        """Scan matching that corrects the odometry only along the directions the scan
        constrains (degeneracy-aware, after Zhang, Kaess and Singh, ICRA 2016).

        The correlative search is read as a distribution over the search box (weights
        ``exp((S - S_max) / match_temperature)``, Olson 2009,
        :func:`~probmap.slam.laser.scan_matching.correlative_distribution`). Along a principal axis of
        its translational covariance wider than ``degenerate_sd`` (and 3x the other axis) the
        score is flat (a featureless corridor): there the best pose is only the first of many
        equals, so its offset from the prediction along that axis is dropped before the
        Gauss-Newton refinement, which then moves along the corridor only as far as the
        bilinear field's gradient (real features) takes it. Returns None when the match is not
        trustworthy (mean score below ``min_score``).
        """
        from probmap.slam.laser.scan_matching import (
            correlative_distribution,
            normal_equations,
            refine,
        )

        cfg = self.config
        m = cfg.matcher
        _, cov, best, _ = correlative_distribution(fld, pts, predicted, m, cfg.match_temperature)
        start = best.copy()  # Gauss-Newton starts from here
        vals, vecs = np.linalg.eigh(cov[:2, :2])  # ascending
        if vals[1] > cfg.degenerate_sd**2 and vals[1] > 9.0 * max(vals[0], 0.0):
            # a ridge: flat along vecs[:, 1], sharp across (a broad bowl is not a ridge)
            v = vecs[:, 1]
            start[:2] -= float(v @ (best[:2] - predicted[:2])) * v
            self.degenerate += 1
        pose, _, _ = refine(fld, pts, start, m.iterations, (m.linear_step, m.angular_step))
        score, _, _ = normal_equations(fld, pts, pose)
        if score / pts.shape[0] < cfg.min_score:
            return None
        return pose

    def _propose(
        self, fld: MatchField, pts: NDArray, predicted: NDArray, u: NDArray
    ) -> tuple[NDArray[np.float64], float]:
        """Draw the new pose from the improved proposal; return it and the log-weight increment
        (Grisetti et al. 2007, eqs. 15-18)."""
        from probmap.models.sampling import sample_motion_model_odometry

        cfg = self.config
        matched = None
        if pts.shape[0] >= 10:
            if cfg.degeneracy_guard:
                matched = self._match_guarded(fld, pts, predicted, u)
            else:
                res = match_scan(fld, pts, predicted, cfg.matcher)
                if res.score >= cfg.min_score:
                    matched = res.pose
        if matched is None:
            # no trustworthy match: the odometry motion model (Table 5.6) and the plain weight
            self.failed += 1
            srr, srt, s_r, stt = cfg.odometry_noise
            alphas = (stt**2, s_r**2, srr**2, srt**2)
            prev = compose(predicted, inverse(u))
            new = sample_motion_model_odometry(prev, np.zeros(3), u, alphas, self.rng).reshape(3)
            if not self.sample:
                new = predicted.copy()
            ll = self._log_likelihoods(fld, pts, new[None, :])[0] if len(pts) else 0.0
            return new, float(ll)
        xs = matched + self._offsets
        log_tau = self._log_likelihoods(fld, pts, xs) + self._motion_log_prior(predicted, xs, u)
        top = float(log_tau.max())
        tau = np.exp(log_tau - top)
        eta = float(tau.sum())
        d = xs - matched
        d[:, 2] = wrap_angle(d[:, 2])
        mu_d = tau @ d / eta
        e = d - mu_d
        cov = (tau[:, None] * e).T @ e / eta + np.diag([1e-6, 1e-6, 1e-7])
        mu = matched + mu_d
        if self.sample:
            new = mu + np.linalg.cholesky(cov) @ self.rng.standard_normal(3)
        else:
            new = mu
        new[2] = float(wrap_angle(new[2]))
        return new, top + math.log(eta)

    # ------------------------------------------------------------------ results
    def best(self) -> int:
        """Index of the particle with the largest weight."""
        return int(np.argmax(self.log_w))

    def trajectory(self, k: int) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Scan indices (P,) and sensor poses (P, 3) of particle ``k``'s processed scans."""
        scans, poses = [], []
        node = int(self.nodes[k])
        while node >= 0:
            scans.append(self._node_scan[node])
            poses.append(self._node_pose[node])
            node = self._node_parent[node]
        return np.asarray(scans[::-1], dtype=np.int64), np.asarray(poses[::-1])

    def grid(self, k: int) -> OccupancyGrid:
        """Particle ``k``'s map as an :class:`OccupancyGrid` (cropped)."""
        lo, spec = self.maps.dense(k)
        g = OccupancyGrid.from_log_odds(spec, lo, clamp=self.config.clamp)
        return g.cropped()


def interpolate_trajectory(
    scans: NDArray[np.int64], poses: NDArray[np.float64], odometry: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Poses for every scan: the last processed pose composed with the odometry increment
    since it (scans before the first processed one take the first pose)."""
    idx = np.searchsorted(scans, np.arange(len(odometry)), side="right") - 1
    idx = np.maximum(idx, 0)
    base = scans[idx]
    return compose(poses[idx], between(odometry[base], odometry))


def run_rbpf(
    times: ArrayLike,
    ranges: ArrayLike,
    angles: ArrayLike,
    odometry: ArrayLike | None,
    max_range: float,
    config: RbpfConfig | None = None,
    *,
    mount: ArrayLike = (0.0, 0.0, 0.0),
    sample: bool = True,
    progress: Callable[[int, int], None] | None = None,
    beams: ArrayLike | None = None,
) -> RbpfResult:
    """Run the filter over a sequence of scans.

    Parameters
    ----------
    times : array_like, shape (S,)
        Scan timestamps, seconds.
    ranges : array_like, shape (S, B)
        Ranges, metres.
    angles : array_like, shape (B,) or (S, B)
        Beam angles in the sensor frame, radians: one set for every scan, or one row per scan
        (a log whose scans change geometry; then ``beams`` says how many of each row's
        entries, and of its ranges, the scan has).
    odometry : array_like, shape (S, 3), or None
        Robot odometry poses at the scans. ``None`` (or constant odometry): scan matching alone,
        every scan processed, with a warning.
    max_range : float
        Sensor maximum range, metres.
    config : RbpfConfig, optional
    mount : array_like, shape (3,)
        Sensor pose in the robot frame.
    sample : bool
        See :class:`RbpfSlam`.
    progress : callable, optional
        ``progress(done, total)`` every 50 scans.
    beams : array_like of int, shape (S,), optional
        Beams of each scan, with per-scan ``angles`` (default: all ``B``).

    Returns
    -------
    RbpfResult
        Robot poses of the best particle at every scan time.
    """
    cfg = config or RbpfConfig()
    t = np.asarray(times, dtype=np.float64)
    R = np.asarray(ranges)
    if R.dtype != np.float32:  # float32 logs stay float32 (half the memory); scans are widened
        R = np.asarray(R, dtype=np.float64)  # one at a time in update()
    if R.ndim != 2 or t.shape != (R.shape[0],):
        raise ValueError(f"times (S,) and ranges (S, B) disagree: {t.shape}, {R.shape}")
    if R.shape[0] == 0:
        raise ValueError("no scans to process")
    mnt = np.asarray(mount, dtype=np.float64)
    no_odometry = odometry is None
    if odometry is not None:
        odo = np.asarray(odometry, dtype=np.float64)
        if odo.shape != (R.shape[0], 3) or not np.isfinite(odo).all():
            raise ValueError(f"odometry must be finite with shape ({R.shape[0]}, 3)")
        no_odometry = bool(np.all(odo == odo[0]))
    if no_odometry:
        warnings.warn(
            "the log has no odometry: running on scan matching alone (every scan processed)",
            UserWarning,
            stacklevel=2,
        )
        odo = np.zeros((R.shape[0], 3))
        cfg_m = cfg.matcher
        from dataclasses import replace

        cfg = replace(
            cfg,
            linear_update=0.0,
            degeneracy_guard=False,
            matcher=replace(cfg_m, linear_window=max(cfg_m.linear_window, 0.3),
                            angular_window=max(cfg_m.angular_window, 0.2)),
        )  # fmt: skip
    A = np.asarray(angles, dtype=np.float64)
    nb = np.full(R.shape[0], R.shape[1], dtype=np.int64)
    if A.ndim == 2:
        if A.shape != R.shape:
            raise ValueError(f"per-scan angles {A.shape} and ranges {R.shape} disagree")
        if beams is not None:
            nb = np.asarray(beams, dtype=np.int64)
            if nb.shape != (R.shape[0],) or np.any(nb < 1) or np.any(nb > R.shape[1]):
                raise ValueError(f"beams must be {R.shape[0]} counts in [1, {R.shape[1]}]")
    elif A.shape != (R.shape[1],):
        raise ValueError(f"angles {A.shape} and ranges {R.shape} disagree")
    sensor_odo = compose(odo, mnt)
    t0 = time.perf_counter()
    slam = RbpfSlam(cfg, A[0, : nb[0]] if A.ndim == 2 else A, max_range, sample=sample)
    n = R.shape[0]
    for i in range(n):
        if i == 0 or no_odometry or slam.moved_enough(sensor_odo[i]):
            if A.ndim == 2:
                slam.update(i, R[i, : nb[i]], sensor_odo[i], A[i, : nb[i]])
            else:
                slam.update(i, R[i], sensor_odo[i])
        if progress is not None and (i % 50 == 49 or i == n - 1):
            progress(i + 1, n)
    k = slam.best()
    scans, sensor = slam.trajectory(k)
    if no_odometry:
        full = np.empty((n, 3))
        full[scans] = sensor
        # every scan is processed, so there is nothing to fill
    else:
        full = interpolate_trajectory(scans, sensor, sensor_odo)
    robot = compose(full, inverse(mnt))
    robot[:, 2] = wrap_angle(robot[:, 2])
    grid = slam.grid(k)
    return RbpfResult(
        grid=grid,
        times=t.copy(),
        poses=robot,
        processed=slam.processed,
        resamples=slam.resamples,
        neff=np.asarray(slam.neff),
        failed_matches=slam.failed,
        map_bytes=slam.map_bytes,
        seconds=time.perf_counter() - t0,
    )
