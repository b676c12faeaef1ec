"""Localization pipeline: a grid map + a laser log with odometry -> an MCL trajectory.

Used by ``probmap localize``; the core algorithm is :class:`~probmap.filters.mcl.MonteCarloLocalization`.
The filter updates when the odometry has moved ``update_distance`` or turned ``update_angle``
since the last update (between updates scans are skipped, as in ROS amcl), never while the
robot stands still, using every ``beam_step``-th beam with the likelihood field model, its
log-likelihood tempered as if a scan held ``independent_beams`` independent beams. After each
update the scan is matched against the map near the estimate, and the cloud follows the scan
where the odometry contradicts it clearly (``match_window``). A run says when it lost track
(its cloud spread, left the map, jumped, or its scans stopped fitting the map at a tight
estimate) and when it recovered (:class:`LostReport`); while lost, augmented MCL injects random
particles. A global localization reports the places its particles hold
(:attr:`LocalizationRun.hypotheses`) and claims convergence only for one tight cluster whose
scans fit the map over ``converged_updates`` updates, and searches again when its particles
collapsed on a place that does not fit. A reference trajectory is compared at its own times, the run interpolated
between its updates (:func:`trajectory_errors`): it never changes the run.

The map is a map_server map or a graph-SLAM session (``probmap slam grid --save-session``):
:func:`load_localization_map` reads either, and renders a session's occupancy grid at its
optimized poses.

Frames: the particles are *robot* poses, moved by the robot's odometry; the laser sits at
``laser_offset`` in the robot frame (its mounting: :func:`laser_offset_of` reads it from a log's
robot and laser poses), so a scan is weighed from ``compose(particle, laser_offset)``. Maps and
sessions are built from laser poses, and the run gives both trajectories
(:attr:`LocalizationRun.poses`, the robot's; :attr:`LocalizationRun.laser_poses`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._checks import require_at_least
from probmap.models.grid_map import GridGeometry
from probmap.pipelines._localize_eval import interpolate_run, trajectory_errors
from probmap.pipelines._localize_map import LocalizationMap, load_localization_map
from probmap.pipelines._localize_track import laser_offset_of, match_times

__all__ = [
    "FilterLostWarning",
    "LocalizationMap",
    "LocalizationRun",
    "LocalizeConfig",
    "LostReport",
    "laser_offset_of",
    "load_localization_map",
    "global_particle_count",
    "localize_scans",
    "interpolate_run",
    "match_times",
    "trajectory_errors",
]


@dataclass(frozen=True)
class LocalizeConfig:
    """Parameters of a localization run.

    Parameters
    ----------
    n_particles : int
        Particles while tracking; with ``kld``, the fewest the filter keeps.
    global_localization : bool
        Start from particles uniform over free space instead of around ``initial_pose``.
    augmented : bool
        Recovery: augmented MCL (random particles from free space while the measurement
        likelihood drops, Table 8.3) while the filter is lost (see ``lost_spread``): how a filter
        that lost track finds the robot again. Always on for global localization. Not while
        tracking: on real logs the scans fit some places of a map worse than others, and random
        particles injected there (even 2 % of them at each update) lure the filter to
        look-alike places (Intel: relation error 0.06 m without, 1.2 m with).
    alpha_slow, alpha_fast : float
        Decay rates of augmented MCL's long- and short-term average likelihoods (Table 8.3).
    max_random_fraction : float
        At most this fraction of the particles is replaced by random ones at a resampling
        (:class:`~probmap.filters.mcl.MCLConfig`).
    initial_pose : (x, y, theta) or None
        Start pose of the robot in the map frame; None takes the first odometry pose (the
        odometry frame is then assumed to coincide with the map frame at the start).
    initial_std : (float, float, float)
        Standard deviations (m, m, rad) of the initial Gaussian.
    alphas : (float, float, float, float)
        Odometry model noise (Table 5.6) of a step of ``noise_distance``.
    noise_distance : float or None
        The ``alphas`` are the noise of a step this long (m): the odometry between two
        updates that spans ``k`` such steps is sampled with the variances divided by ``k``
        (:func:`~probmap.models.sampling.odometry_step_count`), the noise of the chain of
        short steps it stands for. Table 5.6 as printed grows the variances with the square
        of the step, so a log with a scan every metre (the Freiburg campus) got five times
        the noise per metre of one with a scan every 20 cm: rotations with a standard
        deviation of 18 deg per metre of straight driving with these ``alphas``, 8 deg as a
        chain. 0.2 m: the longest of the steps the defaults were judged at (the median
        update spans 0.11 m on Intel, 0.13 m on Freiburg 079, 0.20 m on the hospital), which
        this leaves as they were. None: as printed.
    update_distance, update_angle : float
        Motion (m, rad) that triggers a filter update. The filter never updates while the
        odometry has not moved at all, even with both at 0.
    beam_step : int
        Use every ``beam_step``-th beam.
    independent_beams : float or None
        Temper the likelihood field: a scan counts as this many independent beams, whatever
        the number used (:func:`~probmap.filters.mcl.mcl_likelihood_exponent`); None counts
        every beam as independent.
    min_ess_fraction : float or None
        Temper a scan further where it would leave fewer than this fraction of effective
        particles (:func:`~probmap.filters.mcl.mcl_adaptive_exponent`): the first scans of a
        global localization then keep every place that fits, not the luckiest random pose.
    free_threshold : float
        Cells with occupancy probability below this are free space for random particles.
    seed : int
    converged_weight, converged_spread, converged_matched, converged_see_through, see_through_margin : float
        Global localization has converged once the particles form one cluster
        (:func:`~probmap.filters.mcl.particle_clusters`) holding at least
        ``converged_weight`` of the weight, with a spread (m) of at most ``converged_spread``,
        for ``lost_updates`` updates in a row, and, for ``converged_updates`` updates in a row,
        one cluster held that weight and the last ``lost_updates`` scans fit the map seen from
        its estimate: on average at
        least ``converged_matched`` of their beams end within ``2 sigma_hit`` of an obstacle
        (:attr:`LocalizationRun.matched`). A cloud that collapsed on a look-alike place fits
        worse (Intel, 20,000 particles from random scans: 0.65-0.67 there, 0.96-1.00 where it
        was right), and on average at most ``converged_see_through`` of their beams run
        through the map's walls there, longer by ``see_through_margin`` m than the ray cast
        from the estimate (:meth:`~probmap.models.likelihood_field.LikelihoodField.see_through_fraction`):
        a look-alike place can fit where beams end (Freiburg 079: 0.83-0.87) while a quarter
        or more of them cross its walls (2-9 % where it was right: people, open doors). Until
        then the run reports its hypotheses, not a position; a global localization whose scans
        stop fitting so (not lost yet) had not converged, and searches the whole map again.
    lost_spread : float
        The filter counts as lost once its particles' spread (metres, ``sqrt(var_x +
        var_y)``) stays above this, or its estimate stays off the map's free space (outside the
        grid, on an unknown or occupied cell), for ``lost_updates`` updates in a row after it
        had converged (see ``converged_weight``; a tracking run starts converged), or its
        scans stop fitting the map (``lost_matched``). It has recovered once, for
        ``lost_updates`` updates in a row, the cloud is tight and on free space and its last
        ``lost_updates`` scans fit the map as a converged global localization's must (a mean
        :attr:`LocalizationRun.matched` of at least ``converged_matched``).
    lost_updates : int
        Consecutive updates beyond (within) those bounds before the filter counts as lost
        (recovered).
    lost_jump : float
        The filter also counts as lost at once when its estimate jumps more than this (m)
        against the odometry from one update to the next; a jump also breaks a run of good
        updates while lost. Tracking, the estimate follows the odometry between updates:
        a jump means it had lost track, or has.
    lost_matched : float
        The filter also counts as lost when its particles are tight but in the wrong place:
        when, for ``lost_updates`` updates in a row, its last ``lost_updates`` scans fit the map
        seen from its estimate with on average fewer than this fraction of their beams ending
        within ``2 sigma_hit`` of an obstacle, of the beams that end on a cell the map has
        observed (a beam into the map's unknown is no evidence either way; where none ends on
        one, the scan counts as fitting). Tracking right, the 10-update average over all beams
        (:attr:`LocalizationRun.matched`) stays above 0.5 on Intel, Freiburg 079 and the Intel
        bag (0.9 or more most of the time). The hospital's dips below 0.3 four times, to
        0.17-0.26, for 4-12 updates; counted over the beams that end on observed cells, for 4-8
        (its robot looks 30-40 m down halls the map never saw): the bound holds there by two
        updates. Counted over all beams, 12 updates at 2,258 s reported a false lost span.
    lost_turn : float
        The filter also counts as lost at once when its estimate has turned more than this
        (rad) against the odometry over the last ``2 lost_updates`` updates while, on average
        over the last ``lost_updates``, more than ``converged_see_through`` of its beams run
        through the map's walls and fewer than ``converged_matched`` end near an obstacle
        (:func:`~probmap.pipelines._localize_track.turned_against_odometry`):
        a tight cloud pulled to a turned, look-alike pose (Freiburg 079). Tracking right, the
        estimate turns at most 13-18 deg against the odometry over 20 updates on Intel and
        the hospital, and its beams cross walls rarely where it does. While lost so, no
        random particles are drawn: the scans fit a wrong place better than the right one
        there, and random particles lure the filter further off (Freiburg 079: a relation
        error of 1.77 m with them, 0.27 m without); the run reports the span. Any run counts
        as recovered only when, on average, at most ``converged_see_through`` of its beams
        cross walls again. (Where its scans stop fitting too, ``lost_matched``, or it
        spreads, random particles search as for any lost filter.)
    lost_random_fraction : float
        While a filter that had converged is lost, this fraction of its particles is replaced
        by random ones at each resampling, whatever augmented MCL's averages say (a cloud that
        never fit gives ``w_fast`` no drop below ``w_slow``), and no more
        (``max_random_fraction`` applies before convergence). The rest keep the place it lost track at: a filter a metre off finds the
        robot again nearby, where a cloud replaced at once by particles over a large building
        (the hospital, 460 x 260 m) wanders.
    kld : bool
        KLD-sampling (Table 8.4) once the filter knows where the robot is (tracking, or a
        global localization after its claim): each resampling draws as many particles as the
        cloud's spread needs, between ``n_particles`` and the global count below. A tight
        cloud keeps ``n_particles``; a filter that lost track and spreads gets more. Not
        during a global search: there the cloud gathers on a few places within 3-4 updates,
        the count would fall to ``n_particles`` and the rival places would die with the
        particles that held them (Intel, 50 random starts: 1 claim 9.9 m off, none with the
        count kept). False: always the count it started with.
    particle_density : float
        A global localization starts with this many particles per square metre of free space
        (about eight per 0.5 x 0.5 m of floor, over all headings), at least ``n_particles``
        and at most ``max_particles``, kept until it claims a place. The same count bounds
        KLD-sampling afterwards. A fixed count serves
        buildings of different sizes unequally: 20,000 particles give Intel's 700 m2 of floor
        28 per m2, and the hospital's 24,000 m2 less than one (21 of 24 random starts right,
        one claiming a place 4.5 m off).
    max_particles : int
        The most particles ``particle_density`` may ask for (about 100 bytes each, and the
        time per update grows with them); ``n_particles`` is kept even when it is more.
    match_window, match_turn, match_gain : float
        Odometry that contradicts the laser (Freiburg 079 logs every reversing as forward
        driving): after each update, the scan is matched against the map around the estimate
        (:meth:`~probmap.models.likelihood_field.LikelihoodField.local_search`, positions within
        ``match_window`` m, headings within ``match_turn`` rad); when the best pose fits better
        by more than ``match_gain`` log-likelihood per beam, lies inside the window (not on its
        edge) and fits the map there as a converged filter must (``converged_matched``), the
        particles near the estimate are moved with it, as if the odometry had said so. None:
        never. The gain needs the whole scan to fit better, so a corridor, where sliding along
        it changes nothing, does not move the cloud.
    converged_updates : int
        Updates in a row over which a global localization's one cluster must fit the map
        before it claims to know where the robot is (see ``converged_weight``): about 3 m or
        3 rad of motion with the default update thresholds. A look-alike place fits for a few
        metres, rarely for more (Freiburg 079, 50 starts, run until the claim: 10 claims on
        the wrong place with 10 updates, none with 30).
    restart_updates : int or None
        A global localization whose particles form one tight cluster (as ``converged_weight``
        and ``converged_spread`` ask) whose scans do not fit the map there (as
        ``converged_matched`` and ``converged_see_through`` ask) for this many updates in a
        row starts again (:meth:`~probmap.filters.mcl.MonteCarloLocalization.restart`:
        particles uniform over free space): the cloud collapsed on a look-alike and nothing of
        the true place is left in it, and random particles weighed on one scan rarely win
        against a cloud that fits some. Counted in :attr:`LocalizationRun.restarts`. None:
        never.
    refine : bool
        Report, while tracking, the particle estimate refined against the map on the whole
        scan (:func:`~probmap.pipelines._localize_track.refine_pose`: Gauss-Newton on the
        distance field with the cloud as prior) where most beams fit there and it lies within
        the cloud; the particles and their spread are left as they are. False: the best
        cluster's mean.
    wall_margin, reverse_fraction : float or None, float
        Tracking, while the last scan fit the map worse than a converged filter's must
        (``converged_matched``): beams through a wall of the map more than ``wall_margin``
        (m) short of their endpoint count as random readings, and ``reverse_fraction`` of the
        particles move by the odometry reversed (:mod:`probmap.filters.mcl_robust`; None, 0: off).
        Not while a lost filter searches with random particles (lost for any reason but
        ``lost_turn``): its casts along every beam, for a cloud KLD-sampling may have grown
        to the global count, made each update of the Freiburg campus's lost span take
        seconds (80 m beams; the whole log 56 s instead of more than 15 minutes).
    """

    n_particles: int = 2000
    global_localization: bool = False
    augmented: bool = True
    alpha_slow: float = 0.001
    alpha_fast: float = 0.1
    max_random_fraction: float = 1.0
    initial_pose: tuple[float, float, float] | None = None
    initial_std: tuple[float, float, float] = (0.1, 0.1, 0.05)
    alphas: tuple[float, float, float, float] = (0.3, 0.1, 0.1, 0.3)
    noise_distance: float | None = 0.2
    sigma_hit: float = 0.15
    z_hit: float = 0.9
    z_rand: float = 0.1
    max_distance: float = 1.0
    max_range: float | None = None
    update_distance: float = 0.1
    update_angle: float = 0.1
    beam_step: int = 3
    independent_beams: float | None = 10.0
    min_ess_fraction: float | None = 0.3
    free_threshold: float = 0.3
    seed: int = 0
    converged_weight: float = 0.9
    converged_spread: float = 0.5
    converged_matched: float = 0.8
    converged_see_through: float = 0.15
    see_through_margin: float = 0.5
    lost_spread: float = 3.0
    lost_updates: int = 10
    lost_jump: float = 2.0
    lost_matched: float = 0.3
    lost_random_fraction: float = 0.1
    kld: bool = True
    particle_density: float = 30.0
    max_particles: int = 500_000
    match_window: float | None = 0.5
    match_turn: float = math.radians(6.0)
    match_gain: float = 0.3
    refine: bool = True
    lost_turn: float = math.radians(20.0)
    wall_margin: float | None = 0.5
    reverse_fraction: float = 0.05
    restart_updates: int | None = 20
    converged_updates: int = 30

    def __post_init__(self) -> None:
        if self.n_particles <= 0:
            raise ValueError(f"n_particles must be positive, got {self.n_particles}")
        require_at_least("beam_step", self.beam_step, 1)
        k = self.independent_beams
        if k is not None and not (math.isfinite(k) and k > 0):
            raise ValueError(f"independent_beams must be a number > 0, got {k}")
        if not (self.update_distance >= 0 and self.update_angle >= 0):
            raise ValueError("update_distance and update_angle must be non-negative")
        # NaN or inf anywhere would give NaN trajectories: refuse it here, naming the field
        if self.initial_pose is not None and (
            len(self.initial_pose) != 3 or not all(math.isfinite(v) for v in self.initial_pose)
        ):
            raise ValueError(f"initial_pose must be 3 finite numbers, got {self.initial_pose}")
        for name in ("initial_std", "alphas"):
            vals = getattr(self, name)
            if not all(math.isfinite(v) and v >= 0 for v in vals):
                raise ValueError(f"{name} must be finite and non-negative, got {vals}")
        if len(self.initial_std) != 3 or len(self.alphas) != 4:
            raise ValueError("initial_std needs 3 numbers and alphas 4")
        u = self.noise_distance
        if u is not None and not (math.isfinite(u) and u > 0):
            raise ValueError(f"noise_distance must be None or a number > 0 m, got {u}")
        for name in ("sigma_hit", "max_distance", "update_distance", "update_angle"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)}")
        if not (math.isfinite(self.z_hit) and math.isfinite(self.z_rand)):
            raise ValueError(f"z_hit and z_rand must be finite, got {self.z_hit}, {self.z_rand}")
        if self.max_range is not None and not (
            math.isfinite(self.max_range) and self.max_range > 0
        ):
            raise ValueError(f"max_range must be a finite number > 0 m, got {self.max_range}")
        if not 0 <= self.free_threshold <= 1:
            raise ValueError(f"free_threshold must lie in [0, 1], got {self.free_threshold}")
        m = self.wall_margin
        if m is not None and not (math.isfinite(m) and m > 0):
            raise ValueError(f"wall_margin must be None or a finite number > 0 m, got {m}")
        if not 0.0 <= self.reverse_fraction <= 0.5:
            raise ValueError(f"reverse_fraction must lie in [0, 0.5], got {self.reverse_fraction}")
        if not (math.isfinite(self.lost_spread) and self.lost_spread > 0):
            raise ValueError(f"lost_spread must be a finite number > 0 m, got {self.lost_spread}")
        require_at_least("lost_updates", self.lost_updates, 1)
        require_at_least("converged_updates", self.converged_updates, 1)
        if self.restart_updates is not None:
            require_at_least("restart_updates", self.restart_updates, 1)
        if not (math.isfinite(self.particle_density) and self.particle_density > 0):
            raise ValueError(
                f"particle_density must be a number > 0 per m2, got {self.particle_density}"
            )
        require_at_least("max_particles", self.max_particles, 1)
        for name in ("converged_matched", "lost_matched", "lost_random_fraction",
                     "converged_see_through"):  # fmt: skip
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"{name} must lie in [0, 1], got {getattr(self, name)}")
        if self.match_window is not None and not (
            math.isfinite(self.match_window) and self.match_window > 0
        ):
            raise ValueError(
                f"match_window must be a number > 0 m or None, got {self.match_window}"
            )
        if not (math.isfinite(self.match_turn) and self.match_turn >= 0):
            raise ValueError(f"match_turn must be a number >= 0 rad, got {self.match_turn}")
        if not (math.isfinite(self.match_gain) and self.match_gain >= 0):
            raise ValueError(f"match_gain must be a number >= 0, got {self.match_gain}")
        if not 0 <= self.converged_matched <= 1:
            raise ValueError(f"converged_matched must lie in [0, 1], got {self.converged_matched}")
        if not (0 < self.converged_weight <= 1 and 0 < self.converged_spread < math.inf):
            raise ValueError(
                "need 0 < converged_weight <= 1 and a finite converged_spread > 0 m, got "
                f"{self.converged_weight}, {self.converged_spread}"
            )
        if not (math.isfinite(self.see_through_margin) and self.see_through_margin >= 0):
            raise ValueError(f"see_through_margin must be >= 0 m, got {self.see_through_margin}")
        if not (math.isfinite(self.lost_turn) and self.lost_turn > 0):
            raise ValueError(f"lost_turn must be a finite number > 0 rad, got {self.lost_turn}")
        if not (math.isfinite(self.lost_jump) and self.lost_jump > 0):
            raise ValueError(f"lost_jump must be a finite number > 0 m, got {self.lost_jump}")


def global_particle_count(config: LocalizeConfig, free_area: float) -> int:
    """Particles a global localization starts with: ``config.particle_density`` per m2 of
    ``free_area`` (m2), at most ``max_particles`` and at least ``n_particles``; the upper
    bound of KLD-sampling too."""
    n = min(math.ceil(config.particle_density * max(free_area, 0.0)), config.max_particles)
    return int(max(n, config.n_particles))


class FilterLostWarning(UserWarning):
    """The particle filter lost track (:attr:`LocalizationRun.lost` says where and why)."""


@dataclass(frozen=True)
class LostReport:
    """Where a localization run lost track, and where it recovered.

    Attributes
    ----------
    scan_index : int
        The scan of the first update of the run of ``LocalizeConfig.lost_updates`` lost ones.
    time : float
        Its timestamp (s).
    reason : str
        ``"off the map"`` (the estimate left the map's free space), ``"spread"`` (the
        particles spread beyond ``lost_spread``), ``"jump"`` (the estimate jumped more than
        ``lost_jump`` against the odometry from this update to the next: the filter had lost
        track, or has), ``"misfit"`` (the scans stopped fitting the map at the estimate:
        ``LocalizeConfig.lost_matched``) or ``"turn"`` (the estimate turned against the
        odometry while its beams ran through walls: ``LocalizeConfig.lost_turn``) or
        ``"unclaimed"`` and ``"unclaimed: walls"`` (a global localization that had claimed a
        place: its scans stopped fitting the map as a claim needs, too few beams near an
        obstacle or too many through walls, and it searched the whole map again; recovered at
        its next claim).
    value : float
        The spread (m) at that update; for ``"jump"``, the jump (m); for ``"misfit"``, the
        mean fraction of the beams that ended near an obstacle over the last updates (for
        ``"unclaimed"`` too, counted over all beams); for ``"unclaimed: walls"``, the mean
        fraction that ran through walls; for ``"turn"``, the turn (degrees).
    recovered_index : int or None
        The scan of the first update of the run of ``lost_updates`` good ones that followed
        (the filter found the robot again); None when the run ended lost.
    recovered_time : float or None
        Its timestamp (s).
    """

    scan_index: int
    time: float
    reason: str
    value: float
    recovered_index: int | None = None
    recovered_time: float | None = None

    @property
    def recovered(self) -> bool:
        return self.recovered_index is not None

    def describe(self) -> str:
        """One line for a warning, an error message or a summary."""
        what = {
            "off the map": "its estimate left the map's free space",
            "jump": f"its estimate then jumped {self.value:.1f} m against the odometry",
            "misfit": "its scans stopped fitting the map at its estimate (on average "
            f"{self.value:.0%} of the beams near an obstacle)",
            "turn": f"its estimate then turned {self.value:.0f} deg against the odometry while "
            "its scans ran through the map's walls",
            "unclaimed": "its scans no longer fit the map as a claim needs (on average "
            f"{self.value:.0%} of the beams near an obstacle): it searched the map again",
            "unclaimed: walls": "its scans no longer fit the map as a claim needs (on average "
            f"{self.value:.0%} of the beams through its walls): it searched the map again",
        }.get(self.reason, f"its particles spread to {self.value:.1f} m")
        text = f"the filter lost track at scan {self.scan_index} (t = {self.time:.2f} s): {what}"
        if self.recovered_index is not None:
            text += (
                f"; it recovered at scan {self.recovered_index} (t = {self.recovered_time:.2f} s)"
            )
        return text


@dataclass(frozen=True, eq=False)
class LocalizationRun:
    """The estimated trajectory, one row per filter update.

    Attributes
    ----------
    times : (T,) ndarray
        Scan timestamps (s).
    poses : (T, 3) ndarray
        The estimates of the robot pose in the map frame (m, rad): the best cluster's mean,
        refined against the map on the whole scan where that fits
        (``LocalizeConfig.refine``).
    spread : (T,) ndarray
        Positional spread ``sqrt(var_x + var_y)`` of the particles (m).
    scan_index : (T,) int ndarray
        Index of the scan each row used.
    lost : LostReport or None
        Where the filter first lost track (see ``LocalizeConfig.lost_spread``) and where it
        recovered, None if it never lost track.
    converged_index : int or None
        The first row from which the particles formed one tight cluster (0 for tracking);
        None when a global localization never converged.
    hypotheses : tuple of Hypothesis
        The particle set's clusters after the last update, heaviest first (those of at least
        5 % of the weight): one when it knows where the robot is.
    localized : bool
        Whether the run knows where the robot is at the end: it converged, its particles form
        one cluster, and its last ``lost_updates`` scans fit the map there (a mean
        :attr:`matched` of at least ``converged_matched``, a mean :attr:`see_through` of at
        most ``converged_see_through``).
    episodes : tuple of LostReport
        Every time it lost track, in order; only the last one may be unrecovered.
    fit : (T,) ndarray
        ``w_fast / w_slow`` after each update (Table 8.3): the short-term over the long-term
        average likelihood of the scans; well below 1 when the scans stop fitting the map.
    matched : (T,) ndarray
        The fraction of the update's beams (with a return) that end within ``2 sigma_hit`` of
        an obstacle of the map, seen from the estimate.
    see_through : (T,) ndarray
        The fraction of the update's beams (with a return) that run through an obstacle of
        the map, seen from the estimate (``LocalizeConfig.see_through_margin``).
    particles : (N, 3) ndarray or None
        The particle set (robot poses) after the last update (m, rad), for pictures; None
        when it is not kept.
    laser_offset : (3,) ndarray
        The laser's pose in the robot frame (m, rad) the run used.
    restarts : int
        How often a global localization started its search again
        (``LocalizeConfig.restart_updates``).
    particle_count : (T,) int ndarray
        The particles after each update (KLD-sampling, ``LocalizeConfig.kld``, varies it).
    track_times, track : (M,) and (M, 3) ndarray
        The robot's pose at every scan from the first update to the last (m, rad), by the
        odometry between the updates
        (:func:`~probmap.pipelines._localize_track.odometry_track`); what
        :func:`interpolate_run` interpolates. Empty: the poses at the updates only.
    """

    times: NDArray[np.float64]
    poses: NDArray[np.float64]
    spread: NDArray[np.float64]
    scan_index: NDArray[np.int64]
    lost: LostReport | None = None
    particles: NDArray[np.float64] | None = None
    laser_offset: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    episodes: tuple[LostReport, ...] = ()
    converged_index: int | None = 0
    hypotheses: tuple[Any, ...] = ()
    localized: bool = True
    fit: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    matched: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    see_through: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    track_times: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    track: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    restarts: int = 0
    particle_count: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def ended_lost(self) -> bool:
        """Whether the run ended lost: its last episode never recovered."""
        return bool(self.episodes) and not self.episodes[-1].recovered

    @property
    def laser_poses(self) -> NDArray[np.float64]:
        """(T, 3) laser poses in the map frame, ``compose(poses, laser_offset)`` (m, rad): what
        a session's trajectory or a log's laser poses are compared with."""
        from probmap.geometry.se2 import compose

        if self.poses.shape[0] == 0:
            return self.poses.copy()
        return np.asarray(compose(self.poses, self.laser_offset)).reshape(-1, 3)


def localize_scans(
    spec: GridGeometry,
    probability: ArrayLike,
    times: ArrayLike,
    ranges: ArrayLike,
    angles: ArrayLike,
    odometry: ArrayLike,
    log_max_range: float,
    config: LocalizeConfig | None = None,
    *,
    start: int = 0,
    stop: int | None = None,
    max_updates: int | None = None,
    until_localized: bool = False,
    laser_offset: ArrayLike = (0.0, 0.0, 0.0),
    progress: Callable[[int, int], None] | None = None,
    observer: Any = None,
) -> LocalizationRun:
    """Run MCL over a scan sequence.

    Parameters
    ----------
    spec : GridGeometry
        Map geometry.
    probability : (H, W) array_like
        Occupancy probability (NaN unknown) or boolean map.
    times : (S,) array_like
        Scan timestamps (s).
    ranges : (S, B) array_like
        Ranges (m).
    angles : (B,) or (S, B) array_like
        Beam angles (rad) in the laser frame, shared by all scans or one row per scan (a log
        whose scans have 180 or 181 beams: rows padded with NaN ranges).
    odometry : (S, 3) array_like
        The robot's odometry pose at each scan (odometry frame).
    log_max_range : float
        The log's maximum range (m).
    config : LocalizeConfig
    start, stop : int
        Scan range to process.
    max_updates : int, optional
        Stop after this many filter updates.
    until_localized : bool
        Global localization: stop at the first update where the run knows where the robot is
        (:attr:`LocalizationRun.localized` would hold: converged, one cluster, the scans fit
        there), as a user runs it until it says so; within ``stop`` and ``max_updates``.
    laser_offset : (3,) array_like
        The laser's pose ``(x, y, theta)`` in the robot frame (m, rad), e.g. from
        :func:`laser_offset_of`; each particle (a robot pose) sees the scan from
        ``compose(particle, laser_offset)``. Zero puts the laser at the robot centre.
    progress : callable, optional
        ``progress(done, total)`` in scans.
    observer : callable, optional
        Called after every filter update as ``observer(index, estimate, particles, ranges,
        angles)``: the scan index, the :class:`~probmap.filters.mcl.PoseEstimate`, the
        particles (N, 3) after resampling (m, rad; do not modify them), and the beams the update
        used, ranges (B',) in m and angles (B',) in rad (the live view:
        :class:`probmap.viz.live.LocalizationObserver`). If it has a ``finish(run)`` method,
        that is called with the result.

    Warns
    -----
    FilterLostWarning
        Each time the filter loses track, naming the scan (``LocalizationRun.episodes``).
    """
    import warnings

    from probmap.filters.kld import KLDConfig
    from probmap.filters.mcl import FreeSpaceSampler, MCLConfig, MonteCarloLocalization
    from probmap.geometry.se2 import between, compose
    from probmap.models.likelihood_field import LikelihoodField
    from probmap.models.sampling import OdometryMotionModel
    from probmap.pipelines._localize_track import (
        NearbyFreeSpace,
        RefineConfig,
        follow_scan,
        odometry_track,
        refine_pose,
        turned_against_odometry,
    )

    cfg = config or LocalizeConfig()
    t = np.asarray(times, dtype=np.float64)
    r = np.asarray(ranges, dtype=np.float64)
    a = np.asarray(angles, dtype=np.float64)
    odo = np.asarray(odometry, dtype=np.float64)
    s_count = t.shape[0]
    if s_count == 0:
        raise ValueError("the log holds no scans")
    if r.ndim != 2 or r.shape[0] != s_count or odo.shape != (s_count, 3):
        raise ValueError(
            f"need ranges (S, B) and odometry (S, 3) for S={s_count} scans, got {r.shape}, "
            f"{odo.shape}"
        )
    if a.shape not in ((r.shape[1],), r.shape):
        raise ValueError(
            f"angles must be one (B,) row shared by all scans or one per scan (S, B), got "
            f"{a.shape} for ranges {r.shape}"
        )
    if not np.all(np.isfinite(odo)):
        raise ValueError("the log's odometry holds non-finite poses")
    mount = np.array(laser_offset, dtype=np.float64)
    if mount.shape != (3,) or not np.all(np.isfinite(mount)):
        raise ValueError(f"laser_offset must be 3 finite numbers (m, m, rad), got {mount.tolist()}")
    stop = s_count if stop is None else min(stop, s_count)
    if not 0 <= start < stop:
        raise ValueError(f"empty scan range [{start}, {stop})")
    max_range = min(80.0, float(log_max_range)) if cfg.max_range is None else cfg.max_range
    prob = np.asarray(probability)
    lf = LikelihoodField(
        spec,
        prob,
        max_range=max_range,
        sigma_hit=cfg.sigma_hit,
        z_hit=cfg.z_hit,
        z_rand=cfg.z_rand,
        max_distance=cfg.max_distance,
    )
    if prob.dtype == np.bool_:
        free_mask = ~prob
    else:
        free_mask = np.nan_to_num(prob.astype(np.float64), nan=1.0) < cfg.free_threshold
    free = FreeSpaceSampler(spec, free_mask & (lf.distance > 0.15))
    # the cells the map has observed: a beam ending elsewhere is no evidence of a misfit
    known = ~np.isnan(prob) if np.issubdtype(prob.dtype, np.floating) else None
    if known is not None and known.all():
        known = None
    nearby = NearbyFreeSpace(spec, free_mask & (lf.distance > 0.15), free)
    augmented = cfg.global_localization  # tracking: only while lost, set below
    rng = np.random.default_rng(cfg.seed)
    motion = OdometryMotionModel(*cfg.alphas, unit_step=cfg.noise_distance)
    n_global = global_particle_count(cfg, free.cells.size * spec.resolution**2)
    # KLD-sampling once the filter knows where it is: a global search that let the count
    # fall as its cloud gathered lost the rival places with it (Intel: a claim 9.9 m off)
    kld = KLDConfig(n_min=cfg.n_particles, n_max=n_global) if cfg.kld else None
    mcl_cfg = MCLConfig(
        n_particles=n_global if cfg.global_localization else cfg.n_particles,
        augmented=augmented,
        alpha_slow=cfg.alpha_slow,
        alpha_fast=cfg.alpha_fast,
        max_random_fraction=cfg.max_random_fraction,
        independent_measurements=cfg.independent_beams,
        min_ess_fraction=cfg.min_ess_fraction,
        kld=None if cfg.global_localization else kld,
    )
    if cfg.global_localization:
        mcl = MonteCarloLocalization.uniform(lf, motion, rng, free, mcl_cfg)
    else:
        pose0 = odo[start] if cfg.initial_pose is None else np.asarray(cfg.initial_pose, float)
        cov0 = np.diag(np.square(cfg.initial_std))
        mcl = MonteCarloLocalization.from_pose(lf, motion, rng, pose0, cov0, mcl_cfg, free)
    sel = slice(None, None, cfg.beam_step)
    refine_cfg = RefineConfig()
    shared = np.ascontiguousarray(a[sel]) if a.ndim == 1 else None
    rows: list[tuple[float, float, float, float, float, int, float, float, float]] = []
    counts: list[int] = []  # particles after each update (KLD-sampling varies it)
    evidence: list[float] = []  # per update: matched, of the beams ending on observed cells
    last = start
    x0, y0 = (float(v) for v in spec.origin)
    res = float(spec.resolution)
    h, w = free_mask.shape
    converged = not cfg.global_localization
    converged_index: int | None = None if cfg.global_localization else 0
    single = 0  # updates in a row with one tight cluster (a rival alive just before: no claim)
    agree = 0  # updates in a row with one tight cluster whose scans fit
    stuck = 0  # updates in a row with one tight cluster whose scans do not fit
    restarts = 0
    streak: list[tuple[int, str, float]] = []  # the current run of lost-looking updates
    good, k_good = 0, start  # while lost: good updates in a row, and the first of them
    episodes: list[LostReport] = []
    lost: LostReport | None = None  # the open episode
    dropped: int | None = None  # the episode of a dropped claim, until the next claim
    prev: tuple[int, NDArray[np.float64]] | None = None  # the last update's scan and estimate
    turns: list[tuple[int, float]] = []  # per update: scan, estimate's turn less the odometry's
    for k in range(start + 1, stop):
        d = odo[k] - odo[last]
        turn = abs((d[2] + math.pi) % (2 * math.pi) - math.pi)
        moved = math.hypot(d[0], d[1])
        # No update while the robot stands still, whatever the thresholds: every update
        # resamples sooner or later, and resampling without motion noise only removes
        # particles (particle deprivation, Probabilistic Robotics section 8.3.5).
        if (moved < cfg.update_distance and turn < cfg.update_angle) or not (moved or turn):
            continue
        beams = shared if shared is not None else np.ascontiguousarray(a[k, sel])
        est = mcl.update_scan(odo[last], odo[k], r[k, sel], beams, mount)
        last = k
        p = est.best_cluster
        if cfg.match_window is not None and converged:
            if follow_scan(mcl, lf, p, r[k, sel], beams, mount, cfg):
                est = mcl.estimate()
                p = est.best_cluster
        fit = mcl.w_fast / mcl.w_slow if mcl.w_slow > 0 else 1.0
        matched = lf.matched_fraction(p, r[k, sel], beams, mount, 2.0 * cfg.sigma_hit)
        through = lf.see_through_fraction(p, r[k, sel], beams, mount, cfg.see_through_margin)
        q = p  # the reported pose: the cloud's, refined on the whole scan where that fits
        if cfg.refine and converged and lost is None:
            lx, ly, ok = lf.endpoints(r[k], a if a.ndim == 1 else a[k], mount)
            q = refine_pose(lf, p, est.covariance, lx[ok], ly[ok], refine_cfg).pose
        rows.append((t[k], q[0], q[1], q[2], est.spread, k, fit, matched, through))
        counts.append(mcl.n)
        evidence.append(
            matched if known is None
            else lf.matched_fraction(p, r[k, sel], beams, mount, 2.0 * cfg.sigma_hit, known)
        )  # fmt: skip
        if observer is not None:
            observer(k, est, mcl.particles, r[k, sel], beams)
        ix, iy = math.floor((p[0] - x0) / res), math.floor((p[1] - y0) / res)
        on_map = 0 <= ix < w and 0 <= iy < h and bool(free_mask[iy, ix])
        wide = not est.spread <= cfg.lost_spread
        # a tight cloud in the wrong place: its scans stop fitting the map, over many updates
        fits = float(np.mean([row[7] for row in rows[-cfg.lost_updates :]]))
        fits_known = float(np.mean(evidence[-cfg.lost_updates :]))
        misfit = len(rows) >= cfg.lost_updates and fits_known < cfg.lost_matched
        recent = np.array([row[7:] for row in rows[-cfg.lost_updates :]])
        consistent = bool(
            recent.shape[0] >= min(cfg.lost_updates, max_updates or cfg.lost_updates)
            and recent[:, 0].mean() >= cfg.converged_matched
            and recent[:, 1].mean() <= cfg.converged_see_through
        )
        if not converged:  # global localization: one tight cluster that fits, or not yet
            top = mcl.hypotheses()[:1]
            one = bool(top) and top[0].weight >= cfg.converged_weight
            single = single + 1 if one and top[0].spread <= cfg.converged_spread else 0
            tight = single >= min(cfg.lost_updates, max_updates or cfg.lost_updates)
            agree = agree + 1 if one and consistent else 0
            converged = tight and agree >= min(
                cfg.converged_updates, max_updates or cfg.converged_updates
            )
            stuck = stuck + 1 if single >= cfg.lost_updates and not consistent else 0
            if converged:
                converged_index = len(rows) - 1
                if dropped is not None:  # claimed again after a dropped claim
                    episodes[dropped] = dataclasses.replace(
                        episodes[dropped], recovered_index=int(k), recovered_time=float(t[k])
                    )
                    dropped = None
                if cfg.refine:  # the claim's own pose refined, as every one after it
                    lx, ly, ok = lf.endpoints(r[k], a if a.ndim == 1 else a[k], mount)
                    q = refine_pose(lf, p, est.covariance, lx[ok], ly[ok], refine_cfg).pose
                    rows[-1] = (rows[-1][0], q[0], q[1], q[2], *rows[-1][4:])
            elif cfg.restart_updates is not None and stuck >= cfg.restart_updates:
                # one tight cloud whose scans do not fit: a look-alike that took every
                # particle. Nothing of the true place is left to find: start again
                mcl.restart()
                mcl.config = mcl_cfg
                single = stuck = agree = 0
                restarts += 1
        elif cfg.global_localization and lost is None and not consistent:
            converged, converged_index = False, None  # it was wrong: search the map again
            mcl.config = mcl_cfg
            # said, as a lost span: the estimates until the next claim are a search's
            fit_now, walls_now = (float(v) for v in recent.mean(axis=0))
            episodes.append(
                LostReport(int(k), float(t[k]), "unclaimed", fit_now)
                if fit_now < cfg.converged_matched
                else LostReport(int(k), float(t[k]), "unclaimed: walls", walls_now)
            )
            dropped = len(episodes) - 1
            warnings.warn(episodes[-1].describe(), FilterLostWarning, stacklevel=2)
            if mcl.n < n_global:  # with the search's count: KLD-sampling shrank the cloud
                mcl.resize(n_global)
        jump = 0.0
        if prev is not None:  # the previous update converged too
            k1, pose1 = prev  # where the odometry alone takes the previous estimate
            guess = compose(pose1, between(odo[k1], odo[k]))
            jump = math.hypot(p[0] - guess[0], p[1] - guess[1])
        turned = turned_against_odometry(turns, k, p, odo, prev, 2 * cfg.lost_updates)
        prev = (k, np.array(p)) if converged else None
        through10 = float(np.mean([row[8] for row in rows[-cfg.lost_updates :]]))
        if lost is None:
            if converged and jump > cfg.lost_jump:
                streak = [(k1, "jump", jump)]  # lost at once
            elif (
                converged and turned[1] > cfg.lost_turn
                and through10 > cfg.converged_see_through and fits < cfg.converged_matched
            ):  # fmt: skip
                streak = [(turned[0], "turn", math.degrees(turned[1]))]  # lost at once
            elif converged and (wide or not on_map or misfit):
                why = "spread" if wide else "off the map" if not on_map else "misfit"
                streak.append((k, why, float(est.spread) if why != "misfit" else fits_known))
            else:
                streak.clear()
            if streak and (streak[0][1] in ("jump", "turn") or len(streak) >= cfg.lost_updates):
                k0, why, val = streak[0]
                lost = LostReport(int(k0), float(t[k0]), why, val)
                nearby.start(p)
                episodes.append(lost)
                warnings.warn(lost.describe(), FilterLostWarning, stacklevel=2)
                streak.clear()
                good = 0
        elif (
            wide or not on_map or fits < cfg.converged_matched or jump > cfg.lost_jump
            or through10 > cfg.converged_see_through
        ):  # fmt: skip
            good = 0
        else:
            good += 1
            if good == 1:
                k_good = k
            if good >= cfg.lost_updates:  # found again
                episodes[-1] = dataclasses.replace(
                    lost, recovered_index=int(k_good), recovered_time=float(t[k_good])
                )
                lost = None
        mcl.augment = not converged or (cfg.augmented and lost is not None)
        # tracking, where the scan fits worse than a converged filter's must: mcl_robust's pass
        # (not while a lost filter searches with random particles and KLD-sampling's larger
        # count: the pass's casts, 80 m long outdoors, made each update of the campus's lost
        # span take seconds; kept while lost by "turn", which draws no random particles)
        searching = lost is not None and lost.reason != "turn"
        robust = (
            not cfg.global_localization
            and converged
            and not searching
            and matched < cfg.converged_matched
        )
        mcl.wall_margin = cfg.wall_margin if robust else None
        mcl.reverse_fraction = cfg.reverse_fraction if robust else 0.0
        mcl.random_floor = cfg.lost_random_fraction if lost is not None else 0.0
        if lost is not None and lost.reason == "turn" and not (wide or not on_map or misfit):
            mcl.augment, mcl.random_floor = False, 0.0  # random particles lure it further off
        # random particles: over all free space while a global localization converges; near
        # where a lost filter lost track, in a disc that doubles every lost_updates updates
        mcl.free_space = (  # a FreeSpaceSampler by duck typing: sample(n, rng)
            cast(Any, nearby.widen(cfg.lost_updates)) if lost is not None else free
        )
        if converged and mcl.config is mcl_cfg:  # recovery keeps most of its cloud
            mcl.config = dataclasses.replace(
                mcl_cfg, max_random_fraction=cfg.lost_random_fraction, kld=kld
            )
        if progress is not None and len(rows) % 50 == 0:
            progress(k - start, stop - start)
        if until_localized and converged and lost is None and len(mcl.hypotheses()) == 1:
            break
        if max_updates is not None and len(rows) >= max_updates:
            break
    if progress is not None:
        progress(stop - start, stop - start)
    arr = np.array(rows, dtype=np.float64).reshape(-1, 9)
    hyps = tuple(mcl.hypotheses())
    track_scans, track = odometry_track(odo, arr[:, 5].astype(np.int64), arr[:, 1:4])
    run = LocalizationRun(
        arr[:, 0], arr[:, 1:4], arr[:, 4], arr[:, 5].astype(np.int64),
        lost=episodes[0] if episodes else None, particles=np.array(mcl.particles),
        laser_offset=mount, episodes=tuple(episodes), fit=arr[:, 6], matched=arr[:, 7],
        see_through=arr[:, 8], track_times=t[track_scans], track=track,
        converged_index=converged_index, hypotheses=hyps, restarts=restarts,
        particle_count=np.array(counts, dtype=np.int64),
        localized=(
            converged_index is not None and len(hyps) == 1 and lost is None
            and arr.shape[0] > 0
            and float(np.mean(arr[-cfg.lost_updates :, 7])) >= cfg.converged_matched
            and float(np.mean(arr[-cfg.lost_updates :, 8])) <= cfg.converged_see_through
        ),
    )  # fmt: skip
    if observer is not None and hasattr(observer, "finish"):
        observer.finish(run)
    return run
