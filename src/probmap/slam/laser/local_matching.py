"""Local SLAM's settings for :class:`~probmap.slam.laser.submap_slam.SubmapSlam`: the motion
filter, the scan-to-submap matcher, when the wide search runs, when the scan refutes the
odometry, the lidar-only window, and the weights of the local edges."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from probmap._checks import require_nonnegative_finite
from probmap.slam.laser.closures import require_pair
from probmap.slam.laser.scan_matching import MatcherConfig, laser_slam_matcher

__all__ = ["LocalMatch", "LocalMatchingConfig"]


def _local_matcher() -> MatcherConfig:
    """The RBPF's matcher (:class:`~probmap.slam.laser.rbpf.RbpfConfig`) with a wider window,
    a finer angular step and more iterations for local SLAM."""
    return replace(
        laser_slam_matcher(),
        linear_window=0.15,
        angular_window=0.1,
        angular_step=0.01,
        iterations=10,
    )


class LocalMatch(NamedTuple):
    """What one scan-to-submap match did (:meth:`SubmapSlam._match`)."""

    pose: NDArray[np.float64]  # local-SLAM frame; the prediction when the match failed
    searched: bool  # the search ran (enough points, a non-empty submap)
    searched_wide: bool  # the wide search ran after a poor match
    took_wide: bool  # its result was kept: the odometry was off by more than the window
    failed: bool  # no match good enough: the prediction was kept
    refuted: bool = False  # no pose within the odometry's 3 sigma matches nearly as well
    score: float = 0.0  # the match's score (sum over the points)


@dataclass(frozen=True)
class LocalMatchingConfig:
    """Local SLAM of :class:`SubmapSlam`: the motion filter, scan-to-submap matching and the
    weights of the local edges.

    Parameters
    ----------
    min_distance, min_rotation : float
        Motion filter: a scan becomes a node once the odometry moved this far (metres) or turned
        this much (radians) since the last node.
    match_every_scan : bool
        Match the scans the motion filter passes over too (against the same submap, with the
        same matcher, but without inserting them or adding them to the graph), so that every
        scan's reported pose comes from the laser rather than from the odometry increment
        since the last node. Gauss-Newton from the odometry prediction is kept when it scores
        at least ``recover_score`` and stays inside the matcher's window; otherwise the scan
        gets a node's whole search. On the Intel log (13,631 scans, 3,976 nodes) 9,643 of the
        9,655 scans between nodes keep Gauss-Newton and the run takes no measurably longer;
        from the Intel bag, whose glitches need the whole search more often, 15 % longer;
        where every scan is a node (the hospital) nothing. It
        takes odometry glitches out of the trajectory: from the Intel ROS bag, whose scan
        stamps jitter against its odometry by up to 0.9 s, the relation error falls from
        0.0306 to 0.0207 m (composed from the odometry, correction spread alike); from the
        Intel log it is 0.0168 m against 0.0166 m, but rotation 0.31 against 0.48 deg.
        ``False`` composes them from the odometry.
    matcher : MatcherConfig
        Local scan-to-submap matcher (search window around the odometry prediction, match field
        width, usable range).
    min_match_score : float
        Least mean match score (0..1) for local SLAM to trust a match; below it the odometry
        prediction is kept.
    recover_score : float
        Below this mean match score local SLAM searches again in ``recover_window`` around the
        prediction and keeps that match if it scores clearly better (odometry off by more than
        the matcher's window: wheel slip, late timestamps).
    recover_drop : float
        The wide search also runs when a match scores under this fraction of the recent
        nodes' mean score (an exponential average, weight 0.2 on the newest): a match can
        score above ``recover_score`` and still be wrong when the odometry put the window
        beside the true pose. On Freiburg 079, where the odometry logs 6 s of reversing as
        forward driving, matches at the window's edge scored 0.48 against 0.85-0.93 before
        them and turned the map by 7 degrees there (relation error 0.49 m; 0.032 m with the
        drop test). Between 0.7 and 0.8 every log scores as well; 0.6 leaves Freiburg 079
        folded and 0.9 breaks the hospital (0.30 m), whose sparse scans then take more wide
        matches. 0 turns it off.
    recover_window : tuple of float
        ``(metres, radians)``: half-widths of that second search (at twice the matcher's
        steps). Its heading half-width is the matcher's own (0.1 rad): wheel odometry's heading
        over one step is trusted, and a timestamp glitch mostly displaces the scan. A wider one
        (0.35 rad before) let sparse scans turn against odometry that reported straight
        driving: on the hospital at 3,473 s, 91 returns matched 0.31 rad off at a mean score of
        0.42, and in its perturbed copies such turns broke the map (every 2nd scan 1.84 m,
        returns cut at 15 m 8.29 m; 0.17 and 1.41 m with 0.1 rad).
    recover_turn : float
        When even the wide search finds no match (under ``min_match_score``) for a node the
        odometry says turned, its heading is searched once more, ``recover_window``'s heading
        half-width widened by a multiple of that turn: four times the median heading
        correction of the last 50 matched nodes that turned at least 0.1 rad (as a fraction of
        their odometry turns), at most ``recover_turn``. So the odometry's own turn errors,
        measured as the run goes, decide how far a failed match may turn: a skid-steered robot
        or a scan stamped late in a turn gets odometry turns off by a fifth or more, and a log
        with a scan every metre turns tens of degrees between scans; wheel odometry that turns
        right keeps the 0.1 rad search. Without it the Freiburg campus log (odometry rebuilt
        from its corrected log, about 1 m between scans, ``benchmarks/bench_graph_slam.py
        --worker campus``) kept odometry turns off by up to 12 degrees and folded (loop
        relations 39 m off); with it, 0.36 m. Intel, the hospital and Freiburg 079 are
        unchanged: their odometry's corrections stay under a tenth to a fifth of the turn, and
        their matches rarely fail. Searching every failed match up to the whole turn (no
        measurement) broke the hospital with returns cut at 15 m (0.15 to 4.4 m) and the Intel
        bag (0.021 to 0.41 m). 0 turns it off.
    lidar_only_window : tuple of float
        ``(metres, radians)``: half-widths of the wide search when there is no odometry
        (lidar-only SLAM), around the constant-velocity prediction. Its heading half-width is
        wider than ``recover_window``'s: nothing else predicts a turn. It bounds what the
        prediction may miss between two scans: a change of speed of 6 m/s or of turn rate of
        3.5 rad/s at 10 scans a second, 0.6 m/s and 0.35 rad/s at 1 scan a second (slow
        scan rates need steady motion).
    lidar_only_steps : int
        Lidar-only SLAM predicts each scan's pose from the last scan's by the mean of the
        last this-many scan-to-scan steps (a laser turns at a steady rate, so the scan
        count is a steadier clock than stamps that jitter); Gauss-Newton from there is kept
        unless the velocity-times-elapsed-time prediction scores better. On the Intel log a
        prediction from stamps alone lost 1.2 m in a corridor at 2,229 s, where two scans
        stamped out of order zeroed the velocity and the match stayed put along the
        corridor (relation error 0.0877 m). With 4, 5, 7, 10 or 20 steps it scores
        0.0170-0.0175 m, with 3 it slides again (0.090 m); Freiburg 079 scores 0.031 m with
        3, 5 or 10. 10 steps are a second at 10 scans a second.
    local_sd : tuple of float
        Standard deviations ``(metres, radians)`` of the local-SLAM edges (node to previous node
        and node to submap anchor).
    anchor_sd_rate : float
        Growth of a node-to-anchor edge's translational standard deviation per metre between
        the two poses (metres per metre): the edge spans up to a submap's length of local SLAM,
        whose drift (a scale the laser and the wheels disagree on, a corridor that constrains
        the motion along it poorly) grows with the distance, so a long edge claims no more than
        local SLAM can hold. 0.1 assumes a drift of local SLAM under about 10 % of the distance
        (the closure windows assume 15 %).
    odometry_sd, odometry_sd_rate : tuple of float
        The odometry increment between consecutive nodes is an edge too, with standard
        deviations ``odometry_sd + odometry_sd_rate * (distance, |rotation|)`` (metres and
        radians; per metre and per radian). The base equals ``local_sd``: as in Cartographer's
        defaults, odometry and scan matching weigh alike, so where the matcher is fooled (a
        featureless corridor, a crowd, a range scale that disagrees with the wheels) the
        odometry pulls back. ``odometry_sd[0] = 0`` leaves the edge out.
    check_odometry : bool
        Let the scan refute the odometry: when a node's match lies beyond three standard
        deviations of its odometry increment (``odometry_sd`` and ``odometry_sd_rate``), the
        best pose within them is scored too, and if it scores under 90 % of the match the
        increment is left out of the graph, as after a wide search. In a corridor whose
        length the laser cannot see, poses along it score alike, so the odometry stays and
        holds the corridor's length. On Freiburg 079 the odometry logs 6 s of reversing
        (302-308 s) as forward driving, about 0.4 m per node against the scans; each such
        increment, weighed like a scan match, pulled half its error into the map (0.034 m
        relation error without this test, 0.032 m with it, given ``recover_drop``).
        ``False`` keeps every increment that the wide search did not override.
    """

    min_distance: float = 0.2
    min_rotation: float = 0.1
    match_every_scan: bool = True
    matcher: MatcherConfig = field(default_factory=_local_matcher)
    min_match_score: float = 0.25
    recover_score: float = 0.4
    recover_window: tuple[float, float] = (0.6, 0.1)
    recover_drop: float = 0.75
    recover_turn: float = 1.0
    lidar_only_window: tuple[float, float] = (0.6, 0.35)
    lidar_only_steps: int = 10
    local_sd: tuple[float, float] = (0.02, 0.005)
    anchor_sd_rate: float = 0.1
    odometry_sd: tuple[float, float] = (0.02, 0.005)
    odometry_sd_rate: tuple[float, float] = (0.02, 0.02)
    check_odometry: bool = True

    def __post_init__(self) -> None:
        for name in ("match_every_scan", "check_odometry"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")
        steps = self.lidar_only_steps
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise ValueError(f"lidar_only_steps must be a positive integer, got {steps!r}")
        for name in ("min_distance", "min_rotation", "anchor_sd_rate", "recover_turn"):
            require_nonnegative_finite(name, getattr(self, name))
        for name in ("min_match_score", "recover_score", "recover_drop"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"{name} must lie in [0, 1], got {v}")
        for name in ("local_sd", "odometry_sd_rate"):
            require_pair(name, getattr(self, name), positive=True)
        for name in ("recover_window", "lidar_only_window", "odometry_sd"):
            require_pair(name, getattr(self, name), positive=False)
        if self.odometry_sd[0] > 0 and not self.odometry_sd[1] > 0:
            raise ValueError(f"odometry_sd needs a positive rotation part, got {self.odometry_sd}")
