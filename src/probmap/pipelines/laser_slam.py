"""Laser SLAM from a raw laser log or a ROS bag, end to end: read the scans, run submap graph
SLAM (:mod:`probmap.slam.laser.submap_slam`) or the RBPF (:mod:`probmap.slam.laser.rbpf`), write
the map files, the trajectory, the pose graph, a picture, the configuration and a session.

Both methods meet this module at one seam: a :class:`~probmap.datasets.records.ScanBatch` (from
:func:`load_laser_log`) and their configuration (:class:`~probmap.slam.laser.submap_slam.
SubmapSlamConfig` or :class:`~probmap.slam.laser.rbpf.RbpfConfig`); :func:`run_laser_slam` runs
the one the configuration names, :func:`slam_grid` does the whole command. The algorithms never
read or write files; this module does, and the CLI (``probmap slam grid``) only parses options,
calls :func:`slam_grid` and prints what it returns.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._atomic import atomic_outputs, atomic_write
from probmap.grid.occupancy import OccupancyGrid
from probmap.pipelines.slam_report import (  # noqa: F401  (the report's names, as before)
    DOUBT_CELLS,
    VISIT_LENGTH,
    closure_report,
    consistency_report,
    doubt_line,
    doubts_of,
    local_report,
    revisit_report,
)

if TYPE_CHECKING:
    from probmap.datasets.records import ScanBatch
    from probmap.datasets.validate import ReadingReport
    from probmap.pipelines.sessions import SessionInfo, SessionLog
    from probmap.slam.laser.rbpf import RbpfConfig, RbpfResult
    from probmap.slam.laser.submap_slam import SubmapSlam, SubmapSlamConfig

__all__ = [
    "SESSION_NAME",
    "LaserSlamOutput",
    "SubmapSlamRun",
    "load_laser_log",
    "run_laser_slam",
    "run_rbpf_slam",
    "run_submap_slam",
    "slam_grid",
    "slam_log",
    "write_rbpf_slam",
    "write_submap_slam",
    "write_trajectory",
]

#: A laser SLAM method, as ``probmap slam grid --method`` names it.
Method = Literal["graph", "rbpf"]

#: The session file's name inside a folder given where a session path is asked for
#: (``slam grid --save-session/--resume FOLDER``, ``localize --map FOLDER``), as ``-o FOLDER``
#: names its outputs.
SESSION_NAME = "slam.session"


@dataclass(frozen=True, eq=False)
class SubmapSlamRun:
    """What a graph-SLAM run produced and did.

    Attributes
    ----------
    grid : OccupancyGrid
        Every scan integrated at its optimized pose (cropped).
    times : ndarray, shape (S,)
        Scan timestamps, seconds.
    poses : ndarray, shape (S, 3)
        Robot poses at every scan time, map frame (metres, radians).
    sensor_poses : ndarray, shape (S, 3)
        Laser poses at every scan time.
    node_poses : ndarray, shape (N, 3)
        Optimized laser poses of the pose-graph nodes.
    node_scans : ndarray, shape (N,)
        Scan index of each node.
    closures : ndarray, shape (C, 2)
        Accepted loop closures as (node, submap anchor node).
    closure_weights : ndarray, shape (C,)
        Robust weight of each closure edge after the final optimization (1 = fully trusted).
    submaps : int
    searched : int
        Closure searches (node x submap) run.
    optimize_seconds, search_seconds, seconds : float
        Time in the back end, in closure search, and in all (wall, after reading the log).
    duration : float
        Log duration (seconds), for the real-time factor.
    memory_bytes : int
        Largest memory held by submaps, cached closure grids and stored scans.
    slam : SubmapSlam
        The run (its pose graph is written as g2o).
    scans_total : int
        Scans in the input; more than ``len(times)`` when the run was stopped early
        (``stop``): everything above then describes the scans it got to.
    """

    grid: OccupancyGrid
    times: NDArray[np.float64]
    poses: NDArray[np.float64]
    sensor_poses: NDArray[np.float64]
    node_poses: NDArray[np.float64]
    node_scans: NDArray[np.int64]
    closures: NDArray[np.int64]
    closure_weights: NDArray[np.float64]
    submaps: int
    searched: int
    optimize_seconds: float
    search_seconds: float
    seconds: float
    duration: float
    memory_bytes: int
    slam: SubmapSlam
    scans_total: int = -1

    @property
    def interrupted(self) -> bool:
        """Whether the run stopped before the last scan (``stop`` said so)."""
        return 0 <= len(self.times) < self.scans_total

    @property
    def nodes(self) -> int:
        """Pose-graph nodes."""
        return int(len(self.node_scans))

    @property
    def real_time_factor(self) -> float:
        """Log duration over wall time."""
        return self.duration / max(self.seconds, 1e-9)


def load_laser_log(
    path: str | os.PathLike[str],
    *,
    method: Method = "graph",
    end_time: float | None = None,
    bag_options: dict[str, Any] | None = None,
    skip_bad_lines: bool = False,
) -> ScanBatch:
    """The scans a laser SLAM method runs on: :func:`probmap.datasets.open_scans` (a raw CARMEN
    log, a ROS 1/2 bag or a registry name; float32 ranges) and the checks the method needs.

    ``robot_poses`` are the robot's odometry poses. ``laser_poses`` are the laser's: for the
    graph method the laser pose fields of a raw CARMEN log (a bag's scans posed through tf in
    the odometry frame, topics and frames guessed as ``probmap map`` does), for the RBPF the
    robot's odometry composed with the log's laser offset (the filter composes the first
    scan's mounting offset itself). ``end_time`` keeps the first ``end_time`` seconds.

    Raises
    ------
    DatasetError
        Unreadable or malformed input (naming the file and line), or no usable reading.
    ValueError
        For the graph method: fewer than two scans, or poses that are not finite. A log
        without odometry (every pose the same, :func:`has_odometry`) is read: graph SLAM
        runs on the scans alone then, the RBPF too, with a warning.
    """
    poses = "corrected" if method == "graph" else "odometry"
    batch = _open_laser_scans(path, poses, end_time, bag_options, skip_bad_lines)
    if method == "graph":
        _require_scans(path, batch)
    return batch


#: Longest median scan period (seconds) lidar-only SLAM accepts: its wide search covers a
#: change of speed of 0.6 m per scan period, so at 2 scans a second a change of 1.2 m/s.
LIDAR_ONLY_PERIOD = 0.5


def has_odometry(batch: ScanBatch) -> bool:
    """Whether the scans carry odometry: False when every scan has the same laser pose (a
    bag without odometry or tf read in the laser's own frame, a log that writes zeros)."""
    laser = np.asarray(batch.laser_poses)
    return bool(len(laser) and not np.all(laser == laser[0]))


def _open_laser_scans(
    path: str | os.PathLike[str],
    poses: str,
    end_time: float | None,
    bag_options: dict[str, Any] | None,
    skip_bad_lines: bool,
) -> ScanBatch:
    """:func:`probmap.datasets.open_scans` as both grid SLAMs read a log: float32 ranges, the
    scans posed as ``poses`` says (``"corrected"`` or ``"odometry"``). A bag with neither tf
    nor odometry into the laser frame (a handheld or backpack recording) is read in the
    laser's own frame, unless a fixed frame was named: SLAM then runs on the scans alone."""
    from probmap.datasets.scans import open_scans
    from probmap.errors import NoPoseSourceError

    def read(options: dict[str, Any] | None) -> ScanBatch:
        return open_scans(
            path,
            poses=poses,
            dtype=np.float32,
            skip_bad_lines=skip_bad_lines,
            bag_options=options,
            end_time=end_time,
        )

    try:
        return read(bag_options)
    except NoPoseSourceError as exc:
        if (bag_options or {}).get("fixed_frame"):
            raise
        return read({**(bag_options or {}), "fixed_frame": exc.laser_frame})


def _require_scans(path: object, batch: ScanBatch) -> None:
    """Refuse what graph SLAM cannot run on: fewer than two scans, or poses not finite."""
    if len(batch.times) < 2:
        raise ValueError(f"{path}: grid SLAM needs at least 2 scans, found {len(batch.times)}")
    laser = np.asarray(batch.laser_poses)
    if not np.isfinite(laser).all():
        raise ValueError(f"{path}: the scans' odometry poses are not finite")


def run_submap_slam(
    batch: ScanBatch,
    config: SubmapSlamConfig | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
    observer: Callable[..., Any] | None = None,
    stop: Callable[[], bool] | None = None,
    resume: SubmapSlam | None = None,
    save_session: str | os.PathLike[str] | None = None,
    log: SessionLog | None = None,
    log_skipped: int = 0,
    odometry: bool | None = None,
) -> SubmapSlamRun:
    """Run :class:`~probmap.slam.laser.submap_slam.SubmapSlam` over a scan batch (see
    :func:`load_laser_log`) and build the final map.

    Blocks of memory of 4 MiB and more are served from memory maps of their own from then
    on, for the rest of the process (:func:`probmap._memory.map_large_blocks`: with glibc,
    the run's freed temporaries would otherwise stay resident).

    ``odometry``: True uses the scans' odometry poses, False ignores them (lidar-only SLAM:
    a constant-velocity prediction, see ``SubmapSlam.add_scan``), None (the default) uses
    them when the batch has any (:func:`has_odometry`) and a resumed session took them.

    ``observer``, when given, is called after every scan as ``observer(index, slam, ranges,
    angles)`` (the live view: :class:`probmap.viz.live.GraphSlamObserver`); if it has a
    ``finish`` method, that is called with the finished run.

    ``stop``, when given, is asked before every scan; once it returns True the run ends there
    as if the log ended: the graph is optimized and the map built from the scans so far
    (``SubmapSlamRun.interrupted``). The CLI's Ctrl-C handler sets it, so that an interrupted
    run still writes what it mapped. Stopping between scans keeps the state consistent, which
    an exception raised inside a scan's update would not.

    ``resume`` continues a saved run (:func:`~probmap.pipelines.sessions.load_session`) with
    this batch, in the same odometry frame (the rest of a log, or a log that carries on where
    the saved one stopped: every scan after the session's last; see
    :func:`~probmap.pipelines.sessions.resume_batch`); the result then covers every scan of
    the session, and the earlier scans' robot poses use this batch's first mounting offset (a
    robot's laser does not move). ``save_session`` writes the run's state before it is
    finished, to be resumed later (:func:`~probmap.pipelines.sessions.save_session`; its
    header records ``log``, of whose scans ``log_skipped`` were in ``resume`` already, and
    whether the run read the batch to the end).

    Raises
    ------
    ValueError
        When ``batch`` does not start after ``resume``'s last scan.
    """
    from probmap._memory import map_large_blocks, release_freed_memory
    from probmap.geometry.se2 import between, compose, inverse, wrap_angle
    from probmap.slam.laser.submap_slam import SubmapSlam, SubmapSlamConfig

    map_large_blocks()  # freed temporaries leave the process (see probmap._memory)
    cfg = config or SubmapSlamConfig()
    t0 = time.perf_counter()
    times = np.asarray(batch.times, dtype=np.float64)
    laser = np.asarray(batch.laser_poses, dtype=np.float64)
    robot = np.asarray(batch.robot_poses, dtype=np.float64)
    mount = between(robot, laser)  # per scan (constant on every log we know)
    angles = np.asarray(batch.angles, dtype=np.float64)
    beams = np.asarray(batch.beams)
    if resume is not None:
        if not isinstance(resume, SubmapSlam):
            raise TypeError(f"resume must be a SubmapSlam session, got {type(resume).__name__}")
        if config is not None and config != resume.config:
            raise ValueError("a resumed session keeps its own configuration; pass config=None")
        slam = resume
        cfg = slam.config
        if slam.scan_times and len(times) and not times[0] > slam.scan_times[-1]:
            raise ValueError(
                f"the scans start at t = {times[0]:.3f} s, not after the session's last scan "
                f"at t = {slam.scan_times[-1]:.3f} s (drop the scans it holds: "
                "probmap.pipelines.sessions.resume_batch)"
            )
    else:
        slam = SubmapSlam(cfg, max_range=float(batch.max_range))
    earlier = len(slam.scan_times)  # scans of the session before this batch
    found = has_odometry(batch)
    if odometry is None:
        odometry = found if not earlier else not slam.lidar_only
    if odometry and not found:
        raise ValueError(
            "no odometry (every scan has the same pose): run without odometry "
            "(lidar-only SLAM) instead"
        )
    if not odometry and len(times) > 1:
        period = float(np.median(np.diff(times)))
        if period > LIDAR_ONLY_PERIOD:
            raise ValueError(
                f"lidar-only SLAM (no odometry) needs at least {1 / LIDAR_ONLY_PERIOD:g} scans "
                f"a second, and these come {1 / max(period, 1e-9):.2g} a second (median "
                f"period {period:.2f} s): nothing else predicts the motion between them"
            )
    if earlier and odometry == slam.lidar_only:
        was = "without" if slam.lidar_only else "with"
        raise ValueError(f"the resumed session ran {was} odometry: so must its continuation")
    n_total = n = len(times)
    peak = 0
    for i in range(n):
        if stop is not None and i > 1 and stop():
            n = i  # as if the log ended here
            break
        if angles.ndim == 1:
            a, r = angles, batch.ranges[i]
        else:
            a, r = angles[i, : beams[i]], batch.ranges[i, : beams[i]]
        slam.add_scan(times[i], r, a, laser[i] if odometry else None)
        if observer is not None:
            observer(i, slam, r, a)
        if i % 200 == 199 or i == n - 1:
            peak = max(peak, slam.memory_bytes())
            release_freed_memory()  # finished submaps' grids and evicted max-grids
        if progress is not None and (i % 20 == 19 or i == n - 1):
            progress(i + 1, n)  # often enough for a steady rate (and ETA) in the bar
    if slam.lidar_only and len(slam.untracked_scans) > 0.5 * max(len(slam.scan_times), 1):
        raise ValueError(
            f"no odometry, and the scans do not overlap enough to follow the motion: "
            f"{len(slam.untracked_scans):,} of {len(slam.scan_times):,} scans matched nothing "
            f"(lidar-only SLAM assumes scans that overlap and a motion that changes little "
            f"from one scan to the next)"
        )
    if n < n_total:  # stopped early: the scans it got to
        times, mount = times[:n], mount[:n]
    if earlier:  # a resumed session: the result covers all of its scans
        times = np.concatenate([np.asarray(slam.scan_times[:earlier]), times])
        mount = np.concatenate([np.repeat(mount[:1], earlier, axis=0), mount])
    if save_session is not None:
        from probmap.pipelines.sessions import save_session as _save

        _save(slam, save_session, complete=n == n_total, log=log, log_used=log_skipped + n)
    slam.finish()
    release_freed_memory()  # the matching phase's freed pages, before the map is laid out
    _, sensor = slam.trajectory()
    poses = compose(sensor, inverse(mount))
    poses[:, 2] = wrap_angle(poses[:, 2])
    grid = slam.map()
    seconds = time.perf_counter() - t0
    run = SubmapSlamRun(
        grid=grid,
        times=times,
        poses=poses,
        sensor_poses=sensor,
        node_poses=slam.node_poses(),
        node_scans=np.asarray(slam.node_scan, dtype=np.int64),
        closures=slam.closure_edges(),
        closure_weights=slam.closure_weights(),
        submaps=len(slam.submaps),
        searched=slam.searched,
        optimize_seconds=slam.optimize_seconds,
        search_seconds=slam.search_seconds,
        seconds=seconds,
        duration=float(times[-1] - times[0]),
        memory_bytes=peak,
        slam=slam,
        scans_total=earlier + n_total,
    )
    if observer is not None and hasattr(observer, "finish"):
        observer.finish(run)
    return run


def run_rbpf_slam(
    batch: ScanBatch,
    config: RbpfConfig | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
) -> RbpfResult:
    """Run :func:`~probmap.slam.laser.rbpf.run_rbpf` over a scan batch (see
    :func:`load_laser_log` with ``method="rbpf"``): the robot's odometry, and the first scan's
    mounting offset for every scan."""
    from probmap.geometry.se2 import between
    from probmap.slam.laser.rbpf import run_rbpf

    times = np.asarray(batch.times, dtype=np.float64)
    angles = np.asarray(batch.angles, dtype=np.float64)
    robot = np.asarray(batch.robot_poses, dtype=np.float64)
    laser = np.asarray(batch.laser_poses, dtype=np.float64)
    mount = between(robot[0], laser[0])
    return run_rbpf(
        times, np.asarray(batch.ranges), angles, robot, float(batch.max_range), config,
        mount=mount, progress=progress,
        beams=np.asarray(batch.beams) if angles.ndim == 2 else None,
    )  # fmt: skip


def method_of(config: SubmapSlamConfig | RbpfConfig | None) -> Method:
    """``"rbpf"`` for an :class:`~probmap.slam.laser.rbpf.RbpfConfig`, else ``"graph"``."""
    from probmap.slam.laser.rbpf import RbpfConfig

    return "rbpf" if isinstance(config, RbpfConfig) else "graph"


@overload
def run_laser_slam(
    batch: ScanBatch,
    config: SubmapSlamConfig | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
) -> SubmapSlamRun: ...
@overload
def run_laser_slam(
    batch: ScanBatch,
    config: RbpfConfig,
    *,
    progress: Callable[[int, int], None] | None = None,
) -> RbpfResult: ...
def run_laser_slam(
    batch: ScanBatch,
    config: SubmapSlamConfig | RbpfConfig | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
) -> SubmapSlamRun | RbpfResult:
    """The laser SLAM method ``config`` belongs to, over ``batch``: submap graph SLAM
    (:func:`run_submap_slam`; the default) or the RBPF (:func:`run_rbpf_slam`)."""
    from probmap.slam.laser.rbpf import RbpfConfig

    if isinstance(config, RbpfConfig):
        return run_rbpf_slam(batch, config, progress=progress)
    return run_submap_slam(batch, config, progress=progress)


@overload
def slam_log(
    path: str | os.PathLike[str],
    config: SubmapSlamConfig | None = None,
    *,
    end_time: float | None = None,
    progress: Callable[[int, int], None] | None = None,
    skip_bad_lines: bool = False,
    bag_options: dict[str, Any] | None = None,
) -> SubmapSlamRun: ...
@overload
def slam_log(
    path: str | os.PathLike[str],
    config: RbpfConfig,
    *,
    end_time: float | None = None,
    progress: Callable[[int, int], None] | None = None,
    skip_bad_lines: bool = False,
    bag_options: dict[str, Any] | None = None,
) -> RbpfResult: ...
def slam_log(
    path: str | os.PathLike[str],
    config: SubmapSlamConfig | RbpfConfig | None = None,
    *,
    end_time: float | None = None,
    progress: Callable[[int, int], None] | None = None,
    skip_bad_lines: bool = False,
    bag_options: dict[str, Any] | None = None,
) -> SubmapSlamRun | RbpfResult:
    """Read a raw CARMEN log, a ROS 1/2 bag or a registry name (:func:`load_laser_log`) and
    run the laser SLAM method ``config`` belongs to (:func:`run_laser_slam`; submap graph SLAM
    by default).

    ``end_time`` keeps the scans of the first ``end_time`` seconds only; ``skip_bad_lines``
    skips and counts malformed or implausible lines instead of failing; ``bag_options`` a
    bag's topics and frames (guessed when not given).
    """
    batch = load_laser_log(
        path,
        method=method_of(config),
        end_time=end_time,
        bag_options=bag_options,
        skip_bad_lines=skip_bad_lines,
    )
    return run_laser_slam(batch, config, progress=progress)  # type: ignore[arg-type]


def write_trajectory(path: str | os.PathLike[str], times: ArrayLike, poses: ArrayLike) -> Path:
    """Write ``time,x,y,theta`` rows atomically (timestamps with microseconds)."""
    t = np.asarray(times, dtype=np.float64)
    p = np.asarray(poses, dtype=np.float64)
    with atomic_write(path, "w") as f:
        f.write("time,x,y,theta\n")
        for ti, (x, y, th) in zip(t, p, strict=True):
            f.write(f"{ti:.6f},{x:.6f},{y:.6f},{th:.6f}\n")
    return Path(path)


def write_submap_slam(
    prefix: str | os.PathLike[str],
    run: SubmapSlamRun,
    *,
    report: dict[str, Any] | None = None,
    title: str | None = None,
) -> list[Path]:
    """Write ``PREFIX.yaml/.pgm/.npz/.png`` (the map), ``PREFIX.trajectory.csv`` (robot pose
    at every scan time), ``PREFIX.g2o`` (the optimized pose graph, laser poses, without the
    closures the pairwise check left out) and
    ``PREFIX.plot.png`` (map, trajectory and accepted closures, axes in metres), and with
    ``report`` (:func:`closure_report`, :func:`consistency_report`) ``PREFIX.report.json``
    and red boxes in the picture at its ``doubts``; all-or-nothing (a missing folder is
    created). ``title`` heads the picture (the prefix's name by default).
    Returns the paths written."""
    from probmap._memory import release_freed_memory
    from probmap.datasets.g2o import write_pose_graph_g2o
    from probmap.grid.io import save_map
    from probmap.viz.laser_slam import save_graph_slam_figure

    prefix = Path(prefix)
    with atomic_outputs():
        files = list(save_map(prefix, run.grid))
        files.append(write_trajectory(f"{prefix}.trajectory.csv", run.times, run.poses))
        g = run.slam.graph
        info = g.information
        used = info.reshape(len(info), -1).any(axis=1)  # closures left out have none
        files.append(
            write_pose_graph_g2o(
                f"{prefix}.g2o", g.poses, g.edges[used], g.measurements[used], info[used]
            )
        )
        release_freed_memory()  # what encoding the map freed, before the picture is drawn
        files.append(
            save_graph_slam_figure(
                f"{prefix}.plot.png", run, title=title or prefix.name,
                doubts=(report or {}).get("doubts", ()),
            )
        )  # fmt: skip
        if report is not None:
            import json

            with atomic_write(f"{prefix}.report.json", "w") as f:
                json.dump(report, f, indent=1)
                f.write("\n")
            files.append(Path(f"{prefix}.report.json"))
    return files


def write_rbpf_slam(
    prefix: str | os.PathLike[str], result: RbpfResult, *, title: str | None = None
) -> list[Path]:
    """Write the RBPF's ``PREFIX.yaml/.pgm/.npz/.png`` (the map of the best particle),
    ``PREFIX.trajectory.csv`` and ``PREFIX.plot.png`` (map and trajectory, axes in metres),
    all-or-nothing. Returns the paths written."""
    from probmap.grid.io import save_map
    from probmap.viz.maps import save_map_figure

    prefix = Path(prefix)
    with atomic_outputs():
        files = list(save_map(prefix, result.grid))
        files.append(write_trajectory(f"{prefix}.trajectory.csv", result.times, result.poses))
        files.append(
            save_map_figure(f"{prefix}.plot.png", result.grid, trajectory=result.poses, title=title)
        )
    return files


@dataclass(frozen=True, eq=False)
class LaserSlamOutput:
    """What :func:`slam_grid` did.

    Attributes
    ----------
    run : SubmapSlamRun or RbpfResult
        The run (its type says which method ran).
    files : list of Path
        Every file written, in the order the summary lists them.
    readings : ReadingReport or None
        How the log's readings were classified.
    skipped_lines : int
        Malformed lines skipped (``skip_bad_lines``).
    scans_read : int
        Scans of this log (a resumed session's earlier scans not counted).
    peak_rss_mib : float
        The process's peak resident memory, MiB.
    report : dict or None
        Graph method: ``{"closures": closure_report(...), "consistency":
        consistency_report(...)}``
        (also written as ``PREFIX.report.json``).
    scans_skipped : int
        Scans of this log a resumed session held already (the log it was saved from, after
        an interrupted run); not in ``scans_read``.
    """

    run: SubmapSlamRun | RbpfResult
    files: list[Path]
    readings: ReadingReport | None
    skipped_lines: int
    scans_read: int
    peak_rss_mib: float
    report: dict[str, Any] | None = None
    scans_skipped: int = 0


def _peak_rss_mib() -> float:
    try:
        import resource
    except ImportError:  # pragma: no cover - not on Windows
        return float("nan")
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux


def slam_grid(
    log: str | os.PathLike[str],
    prefix: str | os.PathLike[str],
    config: SubmapSlamConfig | RbpfConfig | None = None,
    *,
    end_time: float | None = None,
    bag_options: dict[str, Any] | None = None,
    skip_bad_lines: bool = False,
    resume: SubmapSlam | None = None,
    resume_info: SessionInfo | None = None,
    save_session: str | os.PathLike[str] | None = None,
    tum: bool = False,
    command: str | None = None,
    title: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    observer: Callable[..., Any] | None = None,
    stop: Callable[[], bool] | None = None,
    phase: Callable[[str], AbstractContextManager[Any]] | None = None,
    odometry: bool | None = None,
) -> LaserSlamOutput:
    """``probmap slam grid``: read ``log``, run the method ``config`` belongs to (submap graph
    SLAM by default, or continue ``resume``), and write every output under ``prefix``, all or
    none: the map, ``PREFIX.trajectory.csv``, ``PREFIX.plot.png`` and ``PREFIX.config.yaml``
    (the configuration with ``command`` and the probmap version); for the graph method also
    ``PREFIX.g2o``, ``PREFIX.report.json`` (what the closure search did and the
    self-consistency figure) and, with
    ``save_session``, the session file (its state before the final
    optimization, so that ``resume`` continues it); with ``tum`` the trajectory as
    ``PREFIX.tum``.

    A resumed session continues with the scans of ``log`` after its last one
    (:func:`~probmap.pipelines.sessions.resume_batch`, which ``resume_info``, the session's
    header, lets warn of a gap): the log that continues it, or the session's own log after an
    interrupted run.

    ``progress``, ``observer`` and ``stop`` are passed to the run (``observer`` and ``stop``:
    the graph method only; see :func:`run_submap_slam`). ``phase(name)``, when given, is entered
    around each phase: ``"read"``, ``"compute"``, ``"check"`` (graph method) and ``"write"``
    (the CLI's stopwatch). ``odometry``: see :func:`run_submap_slam` (the graph method; the
    RBPF always uses what odometry there is).

    Raises
    ------
    ValueError
        ``resume``, ``save_session``, ``observer`` or ``stop`` with an RBPF configuration, or a
        resumed session with a configuration of its own.
    """
    from probmap._memory import SMALL_BLOCK, map_large_blocks, release_freed_memory
    from probmap.config import write_config

    map_large_blocks()  # freed temporaries leave the process (see probmap._memory)
    phase = phase or (lambda name: nullcontext())
    method = method_of(config)
    if method == "rbpf" and (resume is not None or save_session is not None):
        raise ValueError("--save-session and --resume are for the graph method")
    if method == "rbpf" and (observer is not None or stop is not None):
        raise ValueError("a live view and a partial stop are for the graph method")
    if method == "rbpf" and odometry is False:
        raise ValueError("--no-odometry is for the graph method")
    if resume is not None and config is not None and config != resume.config:
        raise ValueError("--resume continues with the session's own configuration; no --config")
    with phase("read"):
        batch = load_laser_log(
            log,
            method=method,
            end_time=end_time,
            bag_options=bag_options,
            skip_bad_lines=skip_bad_lines,
        )
    source = None
    skipped = 0
    reordered = 0
    if method == "graph":
        from probmap.datasets.scans import in_publication_order
        from probmap.pipelines.sessions import SessionLog, resume_batch

        if odometry is not None:
            lidar_only = not odometry
        elif resume is not None and resume.scan_times:
            lidar_only = resume.lidar_only
        else:
            lidar_only = not has_odometry(batch)
        if lidar_only:  # each scan is predicted from the one before: take them as taken
            batch, reordered = in_publication_order(batch)

        source = SessionLog.of(log, batch)
        if resume is not None:
            batch, skipped = resume_batch(resume, batch, resume_info, log_name=source.name)
    prefix = Path(prefix)
    part: Path | None = None
    try:
        with phase("compute"):
            if method == "rbpf":
                run: SubmapSlamRun | RbpfResult = run_rbpf_slam(
                    batch,
                    config,  # type: ignore[arg-type]
                    progress=progress,
                )
            else:
                # the session is saved before the map is built, into a temporary file; it
                # joins the other outputs (all or none) below
                if save_session is not None:
                    part = _session_part(Path(save_session))
                graph_config = None if resume is not None else config
                try:
                    run = run_submap_slam(
                        batch, graph_config, progress=progress,  # type: ignore[arg-type]
                        observer=observer, stop=stop, resume=resume, save_session=part,
                        log=source, log_skipped=skipped, odometry=odometry,
                    )  # fmt: skip
                except ValueError as exc:  # a log lidar-only SLAM cannot follow: name it
                    raise ValueError(f"{log}: {exc}") from None
                except OSError as exc:  # a full disk: name the session, not its temporary
                    if part is None or part.name not in str(exc):
                        raise
                    reason = os.strerror(exc.errno) if exc.errno else str(exc)
                    raise type(exc)(
                        exc.errno, f"cannot write {save_session}: {reason}", str(save_session)
                    ) from None
        map_large_blocks(SMALL_BLOCK)  # the SLAM is over: few blocks from here on
        used = resume.config if resume is not None else run_config(run, config)
        report: dict[str, Any] | None = None
        if isinstance(run, SubmapSlamRun):
            with phase("check"):
                # this log's scans of the run (a resumed session's earlier ones are not read)
                earlier = run.scans_total - len(batch.times)
                report = {
                    "local": {**local_report(run.slam, run.times), "scans_reordered": reordered},
                    "closures": closure_report(run.slam),
                    "consistency": consistency_report(
                        run.times[earlier:], run.sensor_poses[earlier:], batch
                    ),
                    "revisits": revisit_report(run.slam, run.times),
                }
                report["doubts"] = doubts_of(report)
            release_freed_memory()  # the check's grids, before the files are written
        with phase("write"), atomic_outputs():  # every file or none
            if isinstance(run, SubmapSlamRun):
                files = write_submap_slam(
                    prefix, run, report=report,
                    title=f"graph SLAM: {title}" if title else None,
                )  # fmt: skip
                files.append(write_config(f"{prefix}.config.yaml", used, command=command))
                if save_session is not None and part is not None:
                    import shutil

                    with open(part, "rb") as src, atomic_write(save_session, "wb") as dst:
                        shutil.copyfileobj(src, dst)
                    files.append(Path(save_session))
            else:
                files = write_rbpf_slam(prefix, run, title=title)
                files.insert(-1, write_config(f"{prefix}.config.yaml", used, command=command))
            if tum:
                from probmap.datasets.tum import write_tum

                files.append(write_tum(f"{prefix}.tum", run.times, run.poses))
    finally:
        if part is not None:
            part.unlink(missing_ok=True)
    return LaserSlamOutput(
        run=run,
        files=files,
        readings=batch.readings,
        skipped_lines=batch.skipped_lines,
        scans_read=len(batch.times),
        peak_rss_mib=_peak_rss_mib(),
        report=report,
        scans_skipped=skipped,
    )


def _session_part(target: Path) -> Path:
    """An empty temporary file for the session before it joins the outputs: beside
    ``target`` when its folder exists (named so that a later run removes it if this one is
    killed: :func:`probmap._atomic.sweep_leftovers`), else in the system's temporary folder."""
    from probmap._atomic import temporary_beside

    if target.parent.is_dir():
        return temporary_beside(target)
    import tempfile

    fd, name = tempfile.mkstemp(suffix=".session")
    os.close(fd)
    return Path(name)


def run_config(
    run: SubmapSlamRun | RbpfResult, config: SubmapSlamConfig | RbpfConfig | None
) -> SubmapSlamConfig | RbpfConfig:
    """The configuration a run used (``config``, or the method's defaults when None)."""
    if isinstance(run, SubmapSlamRun):
        return run.slam.config
    from probmap.slam.laser.rbpf import RbpfConfig

    return config if config is not None else RbpfConfig()
