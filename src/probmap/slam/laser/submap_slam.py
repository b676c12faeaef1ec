"""Graph SLAM for laser logs: local SLAM on submaps, verified loop closures and a sparse
pose-graph back end (Hess, Kohler, Rapp and Andor, "Real-Time Loop Closure in 2D LIDAR SLAM",
ICRA 2016; Kuemmerle et al. 2009 for the graph of relations; Probabilistic Robotics ch. 11 for
the full-SLAM view).

Per scan that passes the motion filter (the sensor moved ``min_distance`` metres or turned
``min_rotation`` radians since the last node, odometry):

1. **Local SLAM.** The odometry increment predicts the pose; the scan is matched against the
   older of the two active submaps (correlative search on the nearest-cell score, then
   Gauss-Newton on the bilinear match field: :mod:`probmap.slam.laser.scan_matching`), and inserted
   into both active submaps (:mod:`probmap.slam.laser.submaps`).
2. **Pose graph.** The scan becomes a node. Its edges: to the previous node and to the anchor
   of every submap it was inserted into, with the relative poses local SLAM measured.
3. **Loop closure.** The node's scan is searched against the finished submaps near its current
   estimate, each within a window that grows with the travel between the node and the submap
   along the shortest chain of local-SLAM links and accepted closures (the drift that can have
   accumulated between them), and every ``wide_search_every`` nodes within a wide window. The
   search is exact over the window (branch and bound over multi-resolution max-grids,
   :mod:`probmap.slam.laser.loop_closure`) and refined by Gauss-Newton. A *near* match (small
   window) scoring at least ``closure_min_score`` is added as an edge under a robust cost
   (dynamic covariance scaling by default), so a wrong one is down-weighted instead of bending
   the map. A *far* match (wide window) must be confirmed: earlier nodes, moved by the
   correction it implies, must match the same part of the map within a small window; the
   confirmed closures then act quadratically for one optimization (a robust kernel would
   discount a large correction by its very size), and after it stay quadratic when the
   correction is within a plausible drift (``trust_drift``), robust otherwise.
4. **Optimization** every ``optimize_every`` nodes and after a closure that moves the estimate
   (Levenberg-Marquardt on the sparse normal equations, :mod:`probmap.slam.posegraph.optimize`), warm
   started from the last solution.

A scan the motion filter passes over is matched against the same submap too
(``match_every_scan``), but neither inserted nor added to the graph: its pose is its match's
offset from the last node, and the correction the optimization makes to the next node is
spread over the scans in between (:func:`spread_between_nodes`). The final map re-integrates
every scan at that pose (Table 9.1, once-per-scan rule). Poses of the sensor are estimated;
the caller composes the mounting offset.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._checks import require_at_least, require_nonnegative_finite, require_positive_finite
from probmap.geometry.se2 import between, compose, inverse, wrap_angle
from probmap.grid.occupancy import InverseSensorModel, OccupancyGrid
from probmap.slam.laser.closures import (
    ClosureConfig,
    LoopClosing,
    LoopClosure,
    edge_information,
)
from probmap.slam.laser.local_matching import LocalMatch, LocalMatchingConfig
from probmap.slam.laser.scan_matching import (
    correlative_search,
    normal_equations,
    refine,
    scan_points,
)
from probmap.slam.laser.scan_poses import spread_between_nodes
from probmap.slam.laser.submaps import Submap
from probmap.slam.posegraph.optimize import RobustKernel

__all__ = [
    "LocalMatchingConfig",
    "OptimizationConfig",
    "SubmapConfig",
    "SubmapSlam",
    "SubmapSlamConfig",
    "spread_between_nodes",
]


@dataclass(frozen=True)
class SubmapConfig:
    """Submaps of :class:`SubmapSlam` and the final map: their cells, size and sensor model.

    Parameters
    ----------
    resolution : float
        Cell side of submaps and of the final map, metres.
    scans : int
        Nodes per submap; a new submap starts every ``scans // 2`` nodes, so each node
        is in two submaps.
    field_radius : int
        Cells beyond which the match field is 0.
    p_hit, p_miss : float
        Inverse sensor model of submaps and of the final map.
    max_clear_range : float
        Distance (metres) up to which a no-return reading clears the final map.
    grid_cache : int
        Finished submaps whose match field and max-grids are kept in memory (least recently
        used first out).
    """

    resolution: float = 0.05
    scans: int = 40
    field_radius: int = 3
    p_hit: float = 0.7
    p_miss: float = 0.4
    max_clear_range: float = 10.0
    grid_cache: int = 8

    def __post_init__(self) -> None:
        require_positive_finite("resolution", self.resolution)
        require_nonnegative_finite("max_clear_range", self.max_clear_range)
        require_at_least("scans", self.scans, 2)
        for name in ("grid_cache", "field_radius"):
            require_at_least(name, getattr(self, name), 1)
        if not 0.0 < self.p_miss < 0.5 < self.p_hit < 1.0:
            raise ValueError(f"need 0 < p_miss < 0.5 < p_hit < 1, got {self.p_miss}, {self.p_hit}")


@dataclass(frozen=True)
class OptimizationConfig:
    """The pose-graph back end of :class:`SubmapSlam`: robust cost of the closure edges and when
    Levenberg-Marquardt runs.

    Parameters
    ----------
    robust : str
        Robust cost of closure edges: ``"dcs"``, ``"cauchy"``, ``"huber"`` or ``"none"``.
    robust_scale : float
        Its scale (``Phi`` of DCS, the kernel width of Cauchy and Huber, in units of the
        whitened error).
    every : int
        Nodes between optimizations.
    final_iterations : int
        Largest number of Levenberg-Marquardt iterations of the final optimization.
    """

    robust: RobustKernel = "dcs"
    robust_scale: float = 1.0
    every: int = 50
    final_iterations: int = 50

    def __post_init__(self) -> None:
        require_positive_finite("robust_scale", self.robust_scale)
        for name in ("every", "final_iterations"):
            require_at_least(name, getattr(self, name), 0)
        if self.robust not in ("dcs", "cauchy", "huber", "none"):
            raise ValueError(f"robust must be dcs, cauchy, huber or none, got {self.robust!r}")


# the turning nodes that measure the odometry's turn errors (``recover_turn``): at least this
# turn (radians), the last this many
_TURN_MIN = 0.1
_TURN_SAMPLES = 50


@dataclass(frozen=True)
class SubmapSlamConfig:
    """Parameters of :class:`SubmapSlam`, in four sections. One configuration for every log:
    none of them is tuned to one building (see the README for the assumptions they make).

    Parameters
    ----------
    local : LocalMatchingConfig
        The motion filter, scan-to-submap matching and the weights of the local edges.
    submaps : SubmapConfig
        Cells, size and sensor model of the submaps and of the final map.
    closures : ClosureConfig
        Loop-closure search and verification (:mod:`probmap.slam.laser.closures`).
    optimization : OptimizationConfig
        Robust cost and schedule of the pose-graph optimization.

    Examples
    --------
    In YAML, a file lists only what it changes::

        closures:
          min_score: 0.6
        submaps:
          scans: 30
    """

    local: LocalMatchingConfig = field(default_factory=LocalMatchingConfig)
    submaps: SubmapConfig = field(default_factory=SubmapConfig)
    closures: ClosureConfig = field(default_factory=ClosureConfig)
    optimization: OptimizationConfig = field(default_factory=OptimizationConfig)

    #: keys of the earlier flat layout and where each lives now (for a one-line error)
    MOVED_KEYS: ClassVar[dict[str, str]] = {
        "min_distance": "local.min_distance",
        "min_rotation": "local.min_rotation",
        "match_every_scan": "local.match_every_scan",
        "matcher": "local.matcher",
        "min_match_score": "local.min_match_score",
        "recover_score": "local.recover_score",
        "recover_window": "local.recover_window",
        "local_sd": "local.local_sd",
        "anchor_sd_rate": "local.anchor_sd_rate",
        "odometry_sd": "local.odometry_sd",
        "odometry_sd_rate": "local.odometry_sd_rate",
        "resolution": "submaps.resolution",
        "submap_scans": "submaps.scans",
        "field_radius": "submaps.field_radius",
        "p_hit": "submaps.p_hit",
        "p_miss": "submaps.p_miss",
        "max_clear_range": "submaps.max_clear_range",
        "grid_cache": "submaps.grid_cache",
        "closure_sd": "closures.sd",
        "closure_min_score": "closures.min_score",
        "wide_min_score": "closures.wide_min_score",
        "closure_window": "closures.window",
        "window_growth": "closures.window_growth",
        "max_window": "closures.max_window",
        "wide_window": "closures.wide_window",
        "wide_search_every": "closures.wide_search_every",
        "near_window": "closures.near_window",
        "far_every": "closures.far_every",
        "consensus": "closures.consensus",
        "consensus_nodes": "closures.consensus_nodes",
        "consensus_checks": "closures.consensus_checks",
        "trust_drift": "closures.trust_drift",
        "drift_min_score": "closures.drift_min_score",
        "closure_every": "closures.every",
        "closure_candidates": "closures.candidates",
        "closure_points": "closures.points",
        "robust": "optimization.robust",
        "robust_scale": "optimization.robust_scale",
        "optimize_every": "optimization.every",
        "final_iterations": "optimization.final_iterations",
    }


class SubmapSlam:
    """Graph SLAM with submaps and loop closure, one scan at a time.

    Parameters
    ----------
    config : SubmapSlamConfig, optional
    max_range : float
        Sensor maximum range (metres); readings at or beyond it are "no return".

    Examples
    --------
    >>> slam = SubmapSlam(SubmapSlamConfig(), max_range=80.0)  # doctest: +SKIP
    >>> for t, r, a, odo in scans:  # doctest: +SKIP
    ...     slam.add_scan(t, r, a, odo)
    >>> slam.optimize(); grid = slam.map()  # doctest: +SKIP
    """

    def __init__(self, config: SubmapSlamConfig | None = None, *, max_range: float) -> None:
        from probmap.slam.posegraph.optimize import OptimizerConfig, PoseGraph2D

        self.config = cfg = config or SubmapSlamConfig()
        if not max_range > 0:
            raise ValueError(f"max_range must be > 0 m, got {max_range}")
        self.max_range = float(max_range)
        self.graph = PoseGraph2D(
            OptimizerConfig(
                max_iterations=5,
                robust=cfg.optimization.robust,
                robust_scale=cfg.optimization.robust_scale,
            )
        )
        self._weights = np.ones(0)
        self._model = InverseSensorModel(cfg.submaps.p_hit, cfg.submaps.p_miss, max_clear_range=0.0)
        self._local_info = edge_information(cfg.local.local_sd)
        # per node
        self.local: list[NDArray[np.float64]] = []  # local-SLAM poses (drifting frame)
        self.node_scan: list[int] = []  # scan index of each node
        # per scan
        self.scan_times: list[float] = []
        self.scan_odometry: list[NDArray[np.float64]] = []
        self.scan_node: list[int] = []  # last node at or before each scan
        # each scan's pose relative to its node's local-SLAM pose (zero for a node)
        self.scan_offset: list[NDArray[np.float64]] = []
        self._ranges: list[NDArray[np.float32]] = []
        self._angles: list[NDArray[np.float64]] = []
        self.submaps: list[Submap] = []
        self.active: list[Submap] = []
        self.failed_matches = 0
        self.recovered = 0  # wide re-searches after a poor local match
        self.odometry_refuted = 0  # odometry increments the scan refuted
        self.odometry_gated = 0  # odometry increments left out (the match searched wide)
        self.gated_scans: list[int] = []  # the scans whose node left its odometry out
        self.lidar_only = False  # the scans come without odometry (set by the first scan)
        self.untracked_scans: list[int] = []  # lidar-only: scans that matched nothing
        self._odometry_trusted = True
        # constant-velocity motion model from local SLAM's own poses: the last scan's pose
        # (local-SLAM frame), its time, and the twist per second of the step before it
        self._last_scan_pose: NDArray[np.float64] | None = None
        self._last_scan_time = 0.0
        self._velocity = np.zeros(3)
        # the last lidar_only_steps scan-to-scan steps, local-SLAM frame, oldest first
        self._recent_steps = np.zeros((0, 3))
        self._velocity_base: tuple[float, NDArray[np.float64]] | None = None
        self._score_level: float | None = None  # recent nodes' mean match score
        # recent turning nodes' heading corrections as fractions of the odometry's turn
        self._turn_errors: list[float] = []
        self.turn_searches = 0  # failed matches searched again over a wider heading
        self.optimizations = 0
        self.optimize_seconds = 0.0
        self._last_node_odometry: NDArray[np.float64] | None = None
        self._since_optimize = 0
        self._travel: list[float] = []  # cumulative path length at each node, metres
        self._done = False  # finish() was called
        self.loops = LoopClosing(
            cfg.closures,
            graph=self.graph,
            submaps=self.submaps,
            active=self.active,
            travel=self._travel,
            matcher=cfg.local.matcher,
            min_match_score=cfg.local.min_match_score,
            grid_cache=cfg.submaps.grid_cache,
            full_points=self._full_points,
            local=self.local,
        )

    # ------------------------------------------------------------------ properties
    @property
    def nodes(self) -> int:
        """Pose-graph nodes so far."""
        return len(self.local)

    def node_poses(self) -> NDArray[np.float64]:
        """Current estimates of the nodes' sensor poses, shape (N, 3), map frame."""
        return self.graph.poses  # a copy already

    # ------------------------------------------------------------------ steps
    def add_scan(
        self, time_s: float, ranges: ArrayLike, angles: ArrayLike, odometry: ArrayLike | None
    ) -> bool:
        """Process one scan; returns whether it became a pose-graph node.

        Parameters
        ----------
        time_s : float
            Timestamp, seconds.
        ranges : array_like, shape (B,)
            Ranges, metres (NaN, zero and negative readings are ignored).
        angles : array_like, shape (B,)
            Beam angles in the sensor frame, radians (may differ from scan to scan).
        odometry : array_like, shape (3,), or None
            The sensor's odometry pose (robot odometry composed with the mounting offset).
            None: there is no odometry (lidar-only SLAM). The scan is then matched against
            the active submap around where the mean of the last scans' steps puts it
            (``lidar_only_steps``; or local SLAM's velocity times the time since the last
            scan, when that scores better), by Gauss-Newton and, when that scores poorly or
            leaves the window, by the correlative search with the wide ``lidar_only_window``.
            A run takes odometry with every scan or with none.
        """
        if self._done:
            raise RuntimeError("SubmapSlam.finish() was called: no more scans can be added")
        r = np.asarray(ranges, dtype=np.float64)
        a = np.asarray(angles, dtype=np.float64)
        lidar_only = odometry is None
        if self.scan_times and lidar_only != self.lidar_only:
            have = "without" if self.lidar_only else "with"
            raise ValueError(
                f"scan {len(self.scan_times)}: a run takes odometry with every scan or with "
                f"none, and its scans so far came {have} odometry"
            )
        odo = np.zeros(3) if odometry is None else np.asarray(odometry, dtype=np.float64)
        if r.ndim != 1 or a.shape != r.shape:
            raise ValueError(f"ranges {r.shape} and angles {a.shape} must be 1-D of equal length")
        if odo.shape != (3,) or not np.isfinite(odo).all():
            raise ValueError(f"odometry must be 3 finite numbers, got {odo.tolist()}")
        if not np.isfinite(a).all():
            raise ValueError("angles must be finite")
        self.lidar_only = lidar_only
        offsets = self._scan_offsets()  # (a session saved before they existed: built now)
        scan = len(self.scan_times)
        last = self._angles[-1] if self._angles else None
        if last is not None and last.shape == a.shape and np.array_equal(last, a):
            a = last  # most logs share one beam geometry: keep one copy
        else:
            a = a.copy()
        if lidar_only:  # the laser's own odometry: its pose in the local-SLAM frame
            odo = self._laser_odometry(r, a, float(time_s), scan)
        self.scan_times.append(float(time_s))
        self.scan_odometry.append(odo.copy())
        self._ranges.append(r.astype(np.float32))
        self._angles.append(a)
        cfg = self.config
        if self._last_node_odometry is not None:
            u = between(self._last_node_odometry, odo)
            if (
                math.hypot(u[0], u[1]) < cfg.local.min_distance
                and abs(float(wrap_angle(u[2]))) < cfg.local.min_rotation
            ):
                self.scan_node.append(len(self.local) - 1)
                if lidar_only:
                    rel = between(self.local[-1], odo)
                    rel[2] = float(wrap_angle(rel[2]))
                    offsets.append(rel)
                else:
                    offsets.append(self._offset_between_nodes(r, a, u))
                if lidar_only:  # the constant-velocity model serves lidar-only SLAM alone
                    self._track(float(time_s), compose(self.local[-1], offsets[-1]))
                return False
        self._add_node(scan, r, a, odo)
        self.scan_node.append(len(self.local) - 1)
        offsets.append(np.zeros(3))
        if lidar_only:
            self._track(float(time_s), self.local[-1])
        return True

    def _constant_velocity(self, time_s: float) -> NDArray[np.float64] | None:
        """Where a scan at ``time_s`` would be if the sensor kept local SLAM's last velocity
        (local-SLAM frame): the last scan's pose after a gap of a second or more or a
        timestamp that goes back; None before the first scan."""
        last = self._last_scan_pose
        if last is None:
            return None
        dt = time_s - self._last_scan_time
        if not 0.0 <= dt < 1.0:
            return last.copy()
        return compose(last, self._velocity * dt)

    def _laser_odometry(
        self, r: NDArray, a: NDArray, time_s: float, scan: int
    ) -> NDArray[np.float64]:
        """Lidar-only SLAM: the scan's pose in the local-SLAM frame, matched around the
        constant-velocity prediction (the origin for the first scan). A scan that matches
        nothing keeps the prediction and is recorded in ``untracked_scans``."""
        predicted = self._constant_velocity(time_s)
        if predicted is None or not self.local:
            return np.zeros(3) if predicted is None else predicted
        cfg = self.config
        m = cfg.local.matcher
        pts = scan_points(r, a, self.max_range, m.usable_range, m.beam_skip)
        # stamps that jitter (the Intel bag's by up to 0.9 s, the Intel log's out of order)
        # make the velocity times the time since the last scan a poor guess, where the mean
        # of the last scans' steps is a good one (the laser turns at a steady rate):
        # Gauss-Newton from both, the step's kept unless the other scores better, and only
        # when it scores at least recover_score and recover_drop of the recent level. The
        # velocity's guess counts only inside lidar_only_window of the step's: a velocity
        # measured over stamps 0.05 s apart can put it a radian off.
        assert self._last_scan_pose is not None
        steps = self._recent_steps
        step = steps.mean(axis=0) if len(steps) else np.zeros(3)
        stepped = compose(self._last_scan_pose, step)
        guesses = [stepped]
        off = between(stepped, predicted)
        lin, ang = cfg.local.lidar_only_window
        if math.hypot(off[0], off[1]) <= lin and abs(float(wrap_angle(off[2]))) <= ang:
            guesses.append(predicted)
        level = self._score_level if cfg.local.recover_drop > 0 else None
        floor = cfg.local.recover_score
        if level is not None:
            floor = max(floor, cfg.local.recover_drop * level)
        best: tuple[float, NDArray[np.float64]] | None = None
        for guess in guesses:
            got_gn = self._refine_scored(pts, guess)
            if got_gn is not None and got_gn[1] >= floor and (best is None or got_gn[1] > best[0]):
                best = (got_gn[1], got_gn[0])
        if best is not None:
            return best[1]
        got = self._match(pts, stepped, wide_window=cfg.local.lidar_only_window)
        self.recovered += got.searched_wide
        if got.failed:
            self.untracked_scans.append(scan)
        return got.pose

    def _track(self, time_s: float, pose: NDArray[np.float64]) -> None:
        """Update the constant-velocity model with a scan's local-SLAM pose. The velocity is
        measured over at least 0.05 s: stamps that jitter (two scans a millisecond apart, as
        in the Intel bag) would turn a millimetre of matching noise into metres per second."""
        base = self._velocity_base
        if base is None or not 0.0 <= time_s - base[0] < 1.0:
            self._velocity = np.zeros(3)
            self._velocity_base = (time_s, np.asarray(pose, dtype=np.float64).copy())
        elif time_s - base[0] >= 0.05:
            step = between(base[1], pose)
            step[2] = float(wrap_angle(step[2]))
            self._velocity = step / (time_s - base[0])
            self._velocity_base = (time_s, np.asarray(pose, dtype=np.float64).copy())
        if self._last_scan_pose is not None:
            step = between(self._last_scan_pose, pose)
            step[2] = float(wrap_angle(step[2]))
            keep = self.config.local.lidar_only_steps - 1
            self._recent_steps = np.vstack(
                [self._recent_steps[len(self._recent_steps) - keep :], step]
            )
        self._last_scan_pose = np.asarray(pose, dtype=np.float64).copy()
        self._last_scan_time = time_s

    def _offset_between_nodes(
        self, r: NDArray, a: NDArray, u: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """Pose of a scan that is no node relative to the last node's local-SLAM pose: its
        match against the active submap around the odometry increment ``u`` (the increment
        itself when ``match_every_scan`` is off or the match fails). Changes no state."""
        cfg = self.config
        if not cfg.local.match_every_scan or not self.local:
            return np.asarray(u, dtype=np.float64).copy()
        m = cfg.local.matcher
        pts = scan_points(r, a, self.max_range, m.usable_range, m.beam_skip)
        prev = self.local[-1]
        predicted = compose(prev, u)
        pose = self._refine_only(pts, predicted)
        if pose is None:  # a poor or distant refinement: the node's whole search
            pose = self._match(pts, predicted, turn=abs(float(wrap_angle(u[2])))).pose
        rel = between(prev, pose)
        rel[2] = float(wrap_angle(rel[2]))
        return rel

    def _add_node(self, scan: int, r: NDArray, a: NDArray, odo: NDArray) -> None:
        cfg = self.config
        m = cfg.local.matcher
        pts = scan_points(r, a, self.max_range, m.usable_range, m.beam_skip)
        k = len(self.local)
        if k == 0:
            local = odo.copy()
            self.graph.add_node(local)
        else:
            assert self._last_node_odometry is not None
            u = between(self._last_node_odometry, odo)
            prev = self.local[k - 1]
            predicted = compose(prev, u)
            d = math.hypot(u[0], u[1])
            sxy = cfg.local.odometry_sd[0] + cfg.local.odometry_sd_rate[0] * d
            sth = cfg.local.odometry_sd[1] + cfg.local.odometry_sd_rate[1] * abs(
                float(wrap_angle(u[2]))
            )
            if self.lidar_only:
                local = self._match_local(
                    pts, predicted, wide_window=cfg.local.lidar_only_window, scan=scan
                )
            else:
                local = self._match_local(
                    pts, predicted, (3.0 * sxy, 3.0 * sth), turn=abs(float(wrap_angle(u[2])))
                )
            rel = between(prev, local)
            self.graph.add_node(compose(self.graph.pose(k - 1), rel))
            self.graph.add_edge(k - 1, k, rel, self._local_info)
            if cfg.local.odometry_sd[0] > 0 and not self.lidar_only:
                # the odometry increment as its own edge: where the scan matcher is fooled
                # (a corridor, a crowd, a range scale that disagrees with the wheels) it pulls
                # back. Left out when the match had to search beyond the window around the
                # odometry (the odometry glitched: wheel slip, a late timestamp) or when the
                # scan refutes it (no pose within its 3 sigma matches nearly as well)
                if self._odometry_trusted:
                    self.graph.add_edge(k - 1, k, u, edge_information((sxy, sth)))
                else:
                    self.odometry_gated += 1
                    self.gated_scans.append(scan)
        if self.lidar_only:  # the node's own match is its laser odometry
            self.scan_odometry[scan] = local.copy()
        self._last_node_odometry = local.copy() if self.lidar_only else odo.copy()
        if k:
            step = float(np.hypot(*between(self.local[k - 1], local)[:2]))
            self._travel.append(self._travel[-1] + step)
        else:
            self._travel.append(0.0)
        self.local.append(local)
        self.node_scan.append(scan)
        # submaps: start a new one every submap_scans // 2 nodes
        half = max(cfg.submaps.scans // 2, 1)
        if not self.active or self.active[-1].size >= half:
            sm = Submap(
                len(self.submaps),
                k,
                cfg.submaps.resolution,
                m.sigma,
                cfg.submaps.field_radius,
                self._model,
            )
            self.loops.new_submap(sm)
            self.submaps.append(sm)
            self.active.append(sm)
        with np.errstate(invalid="ignore"):  # submaps hold what the matcher uses
            r_sub = np.where(r < m.usable_range, r, np.nan)
        for sm in self.active:
            in_sub = between(self.local[sm.anchor], local)
            sm.insert(k, in_sub, r_sub, a, self.max_range)
            if sm.anchor != k and sm.anchor != k - 1:
                self.graph.add_edge(sm.anchor, k, in_sub, self._anchor_information(in_sub))
        while self.active and self.active[0].size >= cfg.submaps.scans:
            self._retire_oldest()
        self.loops.add_node(pts)  # closure endpoints: an even subsample of the scan
        if k > 0 and k % cfg.closures.every == 0:
            self.loops.search(k)
        self._since_optimize += 1
        if cfg.optimization.every and (
            self._since_optimize >= cfg.optimization.every or self.loops.pending_correction
        ):
            self.optimize()

    def _turn_widening(self) -> float:
        """How far, as a fraction of the odometry's turn, a failed match's heading is searched
        again (``recover_turn``): four times the median heading correction of the last 50
        matched nodes that turned at least 0.1 rad, as a fraction of their odometry turns, at
        most ``recover_turn``; 0 before 10 such nodes."""
        errs = self._turn_errors
        if len(errs) < 10:
            return 0.0
        return min(self.config.local.recover_turn, 4.0 * float(np.median(errs)))

    def _anchor_information(self, rel: NDArray[np.float64]) -> NDArray[np.float64]:
        """Information of a node-to-anchor edge with relative pose ``rel``: ``local_sd`` with
        the translation part grown by ``anchor_sd_rate`` per metre of the edge's length."""
        cfg = self.config
        rate = cfg.local.anchor_sd_rate
        if rate == 0.0:
            return self._local_info
        sxy = cfg.local.local_sd[0] + rate * math.hypot(float(rel[0]), float(rel[1]))
        return edge_information((sxy, cfg.local.local_sd[1]))

    def _retire_oldest(self) -> None:
        """Finish the oldest active submap and make it a closure-search candidate."""
        done = self.active.pop(0)
        done.finish()
        self.loops.add_candidate(done)

    def _match_local(
        self,
        pts: NDArray,
        predicted: NDArray,
        ball: tuple[float, float] | None = None,
        *,
        wide_window: tuple[float, float] | None = None,
        scan: int = -1,
        turn: float = 0.0,
    ) -> NDArray[np.float64]:
        """Scan-to-submap matching of a new node around the odometry prediction (local-SLAM
        frame); counts failed matches and wide searches, whether the odometry held (``ball``:
        its 3-sigma half-widths, metres and radians, see ``check_odometry``), and keeps the
        recent nodes' score level."""
        got = self._match(pts, predicted, ball, wide_window=wide_window, turn=turn)
        if not got.failed and turn >= _TURN_MIN:
            fix = abs(float(wrap_angle(between(predicted, got.pose)[2])))
            self._turn_errors = [*self._turn_errors[-(_TURN_SAMPLES - 1) :], fix / turn]
        if got.failed and self.lidar_only and scan not in self.untracked_scans[-1:]:
            self.untracked_scans.append(scan)
        if got.searched:  # a match that never ran leaves the gate as the last node set it
            self._odometry_trusted = not (got.took_wide or got.refuted)
        if not got.failed:
            mean = got.score / max(pts.shape[0], 1)
            lv = self._score_level
            self._score_level = mean if lv is None else 0.8 * lv + 0.2 * mean
            self.odometry_refuted += got.refuted
        self.recovered += got.searched_wide
        self.failed_matches += got.failed
        return got.pose

    def _refine_scored(
        self, pts: NDArray, predicted: NDArray
    ) -> tuple[NDArray[np.float64], float] | None:
        """Gauss-Newton alone from ``predicted``: the pose (local-SLAM frame) and its mean
        score when it stays inside the matcher's window, otherwise None."""
        m = self.config.local.matcher
        frame = self._match_frame(pts, predicted)
        if frame is None:
            return None
        anchor, guess, fld = frame
        pose, _, _ = refine(fld, pts, guess, m.iterations, (m.linear_step, m.angular_step))
        score, _, _ = normal_equations(fld, pts, pose)
        d = between(guess, pose)
        if math.hypot(d[0], d[1]) > m.linear_window or abs(float(wrap_angle(d[2]))) > (
            m.angular_window
        ):
            return None
        return _in_local(anchor, pose), score / pts.shape[0]

    def _refine_only(self, pts: NDArray, predicted: NDArray) -> NDArray[np.float64] | None:
        """Gauss-Newton alone from ``predicted`` against the oldest active submap: the pose
        when it scores at least ``recover_score`` and stays inside the matcher's window,
        otherwise None. A scan between nodes is predicted from a node matched moments before
        and under ``min_distance`` of odometry, so this is the match in nearly every case
        (9,643 of 9,655 on the Intel log) at a fraction of the correlative search's cost; an
        odometry glitch moves it beyond the window or lowers its score."""
        got = self._refine_scored(pts, predicted)
        if got is None or got[1] < self.config.local.recover_score:
            return None
        return got[0]

    def _match_frame(self, pts: NDArray, predicted: NDArray) -> tuple[Any, Any, Any] | None:
        """The oldest active submap's anchor pose, ``predicted`` in its frame and its match
        field; None when there is nothing to match (under 10 points, an empty submap)."""
        sm = self.active[0]
        if pts.shape[0] < 10 or sm.size == 0:
            return None
        anchor = self.local[sm.anchor]
        return anchor, between(anchor, predicted), sm.field()

    def _match(
        self,
        pts: NDArray,
        predicted: NDArray,
        ball: tuple[float, float] | None = None,
        *,
        wide_window: tuple[float, float] | None = None,
        turn: float = 0.0,
    ) -> LocalMatch:
        """Match ``pts`` against the oldest active submap around ``predicted`` (local-SLAM
        frame): the correlative search, and the wide one after a poor match (under
        ``recover_score``, or under ``recover_drop`` of the recent level); with ``ball``, the
        test whether the scan refutes the odometry (``check_odometry``). Changes no state."""
        cfg = self.config
        m = cfg.local.matcher
        frame = self._match_frame(pts, predicted)
        if frame is None:
            return LocalMatch(
                predicted, searched=False, searched_wide=False, took_wide=False, failed=True
            )
        anchor, guess, fld = frame
        took_wide = False
        searched_wide = False
        best, _ = correlative_search(fld, pts, guess, m)
        pose, _, _ = refine(fld, pts, best, m.iterations, (m.linear_step, m.angular_step))
        score, _, _ = normal_equations(fld, pts, pose)
        level = self._score_level if cfg.local.recover_drop > 0 else None
        if score / pts.shape[0] < cfg.local.recover_score or (
            level is not None and score / pts.shape[0] < cfg.local.recover_drop * level
        ):
            # a poor match: the odometry may be off by more than the window (wheel slip, a
            # late timestamp); search a wide window once and keep it if it matches better
            lin, ang = cfg.local.recover_window if wide_window is None else wide_window
            wide = replace(
                m,
                linear_window=lin,
                linear_step=2 * m.linear_step,
                angular_window=ang,
                angular_step=2 * m.angular_step,
            )
            best2, _ = correlative_search(fld, pts, guess, wide)
            pose2, _, _ = refine(fld, pts, best2, m.iterations, (m.linear_step, m.angular_step))
            score2, _, _ = normal_equations(fld, pts, pose2)
            searched_wide = True
            if score2 > score + 0.05 * pts.shape[0]:
                pose, score = pose2, score2
                took_wide = True
            failed = score / pts.shape[0] < cfg.local.min_match_score
            extra = self._turn_widening() * turn if failed and turn > 0.0 else 0.0
            if extra > 0.0:
                # still no match, and this odometry's turns have been off: search the
                # heading as far as the turn may be wrong (recover_turn)
                wide = replace(wide, angular_window=ang + extra)
                best2, _ = correlative_search(fld, pts, guess, wide)
                pose2, _, _ = refine(fld, pts, best2, m.iterations, (m.linear_step, m.angular_step))
                score2, _, _ = normal_equations(fld, pts, pose2)
                self.turn_searches += 1
                if score2 > score + 0.05 * pts.shape[0]:
                    pose, score = pose2, score2
                    took_wide = True
        if score / pts.shape[0] < cfg.local.min_match_score:
            return LocalMatch(predicted, True, searched_wide, took_wide, failed=True)
        refuted = False
        if ball is not None and not took_wide and cfg.local.check_odometry:
            d = between(guess, pose)
            if math.hypot(d[0], d[1]) > ball[0] or abs(float(wrap_angle(d[2]))) > ball[1]:
                near = replace(
                    m,
                    linear_window=ball[0],
                    linear_step=ball[0] / 3.0,
                    angular_window=ball[1],
                    angular_step=ball[1] / 3.0,
                )
                best3, _ = correlative_search(fld, pts, guess, near)
                score3, _, _ = normal_equations(fld, pts, best3)
                refuted = score3 < 0.9 * score
        return LocalMatch(
            _in_local(anchor, pose),
            True,
            searched_wide,
            took_wide,
            failed=False,
            refuted=refuted,
            score=float(score),
        )

    def _full_points(self, k: int) -> NDArray[np.float64]:
        """Node ``k``'s scan endpoints with the local matcher's usable range, sensor frame."""
        m = self.config.local.matcher
        s = self.node_scan[k]
        return scan_points(
            self._ranges[s].astype(np.float64), self._angles[s], self.max_range, m.usable_range,
            m.beam_skip,
        )  # fmt: skip

    # ------------------------------------------------------------------ closures (counts)
    @property
    def closures(self) -> list[LoopClosure]:
        """Accepted loop closures, in acceptance order."""
        return self.loops.closures

    @property
    def searched(self) -> int:
        """Branch-and-bound searches run (near, far and consensus checks)."""
        return self.loops.searched

    @property
    def search_seconds(self) -> float:
        """Time spent searching and verifying closures, seconds."""
        return self.loops.search_seconds

    # ------------------------------------------------------------------ back end
    def optimize(self, max_iterations: int | None = None) -> Any:
        """Optimize the pose graph: Levenberg-Marquardt warm-started from the current
        estimates (5 iterations unless ``max_iterations``), closure edges under the robust
        cost. Returns the :class:`~probmap.slam.posegraph.optimize.OptimizeResult` (None before there
        is an edge)."""
        if self.graph.num_edges == 0:
            return None
        t0 = time.perf_counter()
        self.loops.select_consistent()
        result = self.graph.optimize(max_iterations if not self.loops.unguarded else 20)
        self.loops.reguard()
        self._weights = result.weights
        self.optimize_seconds += time.perf_counter() - t0
        self.optimizations += 1
        self._since_optimize = 0
        self.loops.pending_correction = False
        return result

    def closure_weights(self) -> NDArray[np.float64]:
        """Robust weight [0..1] of every accepted closure after the last optimization (1 for a
        closure taken quadratically, 0 for one the pairwise check leaves out)."""
        w = np.ones(self.graph.num_edges)
        w[: len(self._weights)] = self._weights
        out = w[self.loops.edge_indices()]
        out[self.loops.left_out] = 0.0
        return out

    # ------------------------------------------------------------------ sessions
    @property
    def finished(self) -> bool:
        """Whether :meth:`finish` ended the run (no more scans; sessions are saved before)."""
        return self._done

    def finish(self) -> None:
        """Final optimization (up to ``final_iterations``), then release what only matching
        needs: the active submaps are finished and every cached field and max-grid is
        dropped, so building the map does not hold them. The run is over: scans may not be
        added afterwards (``optimize``, ``map`` and ``trajectory`` still work)."""
        if self._done:
            return
        if self.nodes > 1:
            self.optimize(self.config.optimization.final_iterations)
        self.loops.release()
        while self.active:
            self._retire_oldest()
        for sm in self.submaps:
            sm.release()
        self._done = True

    def trajectory(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Times (S,) and sensor poses (S, 3) of every scan, map frame.

        Nodes are at their optimized poses. A scan between two nodes is placed by its own
        match (``match_every_scan``; otherwise the odometry increment) from the previous
        node, and the correction the optimization made to the next node relative to that
        chain is spread over the scans between them (:func:`spread_between_nodes`), so the
        trajectory has no jump at a node.
        """
        times = np.asarray(self.scan_times, dtype=np.float64)
        if self.config.local.match_every_scan:
            chain = np.asarray(self.local, dtype=np.float64).reshape(-1, 3)
        else:  # the offsets are odometry increments: so is the chain from node to node
            odo = np.asarray(self.scan_odometry, dtype=np.float64).reshape(-1, 3)
            chain = odo[np.asarray(self.node_scan, dtype=np.int64)]
        return times, spread_between_nodes(
            self.node_poses(),
            chain,
            np.asarray(self.node_scan, dtype=np.int64),
            np.asarray(self.scan_node, dtype=np.int64),
            np.asarray(self._scan_offsets(), dtype=np.float64).reshape(-1, 3),
            times,
        )

    def _scan_offsets(self) -> list[NDArray[np.float64]]:
        """``scan_offset``; a session saved before it existed composes the odometry."""
        offsets = getattr(self, "scan_offset", None)
        if offsets is None:
            offsets = []
            for i, k in enumerate(self.scan_node):
                base = self.scan_odometry[self.node_scan[k]]
                offsets.append(between(base, self.scan_odometry[i]))
            self.scan_offset = offsets
        return offsets

    def map(self, *, max_clear_range: float | None = None) -> OccupancyGrid:
        """Every scan re-integrated at its optimized pose (Table 9.1, once per scan).

        Returns beyond the matcher's ``usable_range`` count as no return (they clear up to
        ``max_clear_range``), as in the submaps: far returns are the least accurate and would
        spread the map over a much larger area. The grid is laid out once around every
        endpoint, so it never grows (and copies) while scans are integrated.
        """
        cfg = self.config
        usable = cfg.local.matcher.usable_range
        clear = cfg.submaps.max_clear_range if max_clear_range is None else max_clear_range
        clear = min(clear, usable, self.max_range)
        model = InverseSensorModel(cfg.submaps.p_hit, cfg.submaps.p_miss, max_clear_range=clear)
        _, poses = self.trajectory()
        lo = poses[:, :2].min(axis=0)
        hi = poses[:, :2].max(axis=0)
        from probmap.grid._kernels import scan_bounds

        box = np.empty(4)

        def readings(i: int) -> NDArray[np.float64]:
            # scan i's ranges as the map takes them, rebuilt per pass rather than kept for
            # every scan at once (8 bytes a beam)
            r = self._ranges[i].astype(np.float64)
            with np.errstate(invalid="ignore"):
                far = r >= usable
            r[far] = self.max_range
            return r

        for i, p in enumerate(poses):
            r = readings(i)
            with np.errstate(invalid="ignore"):
                hit = np.isfinite(r) & (r > 0) & (r < self.max_range)
            # the layout reaches every endpoint and the clear range along every other beam
            # (dropped readings too): the kernel's bounds of readings of those ranges
            reach = np.where(hit, r, clear)
            scan_bounds(
                p[None, :], reach[None, :], self._angles[i][None, :], True, self.max_range,
                clear, model.thickness, box,
            )  # fmt: skip
            lo = np.minimum(lo, box[[0, 2]])
            hi = np.maximum(hi, box[[1, 3]])
        from probmap.grid.spec import GridSpec

        spec = GridSpec.around(cfg.submaps.resolution, lo[0], hi[0], lo[1], hi[1], margin=4)
        grid = OccupancyGrid(cfg.submaps.resolution, model=model, spec=spec)
        for i, p in enumerate(poses):
            grid.integrate_scan(p, readings(i), self._angles[i], max_range=self.max_range)
        return grid  # laid out on the endpoints: cropping would only copy it

    def closure_edges(self) -> NDArray[np.int64]:
        """Accepted closures as (node, anchor) pairs, shape (C, 2)."""
        return np.asarray([(c.node, c.anchor) for c in self.closures], dtype=np.int64).reshape(
            -1, 2
        )

    def memory_bytes(self) -> int:
        """Bytes held by submaps, cached grids and stored scans (approximate)."""
        n = sum(sm.nbytes for sm in self.submaps)
        n += self.loops.cache_bytes()
        n += sum(r.nbytes for r in self._ranges)
        return n


def _in_local(anchor: NDArray[np.float64], pose: NDArray[np.float64]) -> NDArray[np.float64]:
    """A pose in a submap's frame as a local-SLAM pose (heading wrapped)."""
    out = compose(anchor, pose)
    out[2] = float(wrap_angle(out[2]))
    return out


def inverse_mount(poses: ArrayLike, mount: ArrayLike) -> NDArray[np.float64]:
    """Robot poses from sensor poses and the sensor's mounting pose in the robot frame."""
    out = compose(np.asarray(poses, dtype=np.float64), inverse(np.asarray(mount, dtype=float)))
    out[..., 2] = wrap_angle(out[..., 2])
    return out
