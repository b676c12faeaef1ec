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


# ----------------------------------------------------------------------------- reports
#: Travel per visit of the self-consistency figure, metres (:func:`consistency_report`).
VISIT_LENGTH = 10.0


def _quantiles(x: NDArray[np.float64]) -> dict[str, float]:
    if not len(x):
        return {}
    q = np.quantile(x, [0.5, 0.9, 0.99])
    return {"median": float(q[0]), "p90": float(q[1]), "p99": float(q[2]), "max": float(x.max())}


def local_report(slam: SubmapSlam, times: ArrayLike) -> dict[str, Any]:
    """Where local SLAM overrode the odometry: the times (seconds from the first scan of
    ``times``, the run's scan times) of the nodes whose match was kept from the wide search,
    more than the matcher's window away from the odometry, so that their odometry edge was
    left out. Right after an odometry glitch (a late timestamp, wheel slip); also where local
    SLAM broke (Freiburg 079 at 305-309 s: six in 4 s). Intel has none, its bag 3, the
    hospital 4."""
    t = np.asarray(times, dtype=np.float64)
    t0 = float(t[0]) if len(t) else 0.0
    return {
        "lidar_only": slam.lidar_only,
        "odometry_overridden_s": [float(t[k]) - t0 for k in slam.gated_scans if k < len(t)],
        "untracked_s": [float(t[k]) - t0 for k in slam.untracked_scans if k < len(t)],
        "failed_matches": slam.failed_matches,
        "wide_searches": slam.recovered,
    }


def closure_report(slam: SubmapSlam) -> dict[str, Any]:
    """What the loop-closure search did and how the accepted closures sit in the optimized
    graph: counts (searched, accepted near and far, a far closure's confirmations counted as
    far too; rejected and why, the pairwise check's closures left out among them; trusted,
    down-weighted by the robust cost; pairs of closures compared and found inconsistent) and
    the distribution of the accepted closure edges' residuals (metres, radians)."""
    from probmap.slam.posegraph.optimize import edge_residuals

    loops = slam.loops
    kept = ~loops.left_out  # closures the pairwise check left out are rejected
    far = sum(c.far for c, k in zip(loops.closures, kept, strict=True) if k)
    edges = loops.edge_indices()[kept]
    g = slam.graph
    if len(edges):
        res = edge_residuals(g.poses, g.edges[edges], g.measurements[edges])
    else:
        res = np.zeros((0, 3))
    weights = slam.closure_weights()[kept]
    return {
        "searched": loops.searched,
        "accepted": {"near": int(kept.sum()) - far, "far": far},
        "far_searches": loops.far_searched,
        "far_matches": loops.far_found,
        "rejected": {
            "not_confirmed_by_earlier_nodes": loops.rejected,
            "correction_beyond_drift_bound": loops.drift_rejected,
            "ambiguous_place": loops.ambiguous,
            "inconsistent_with_other_closures": int((~kept).sum()),
        },
        "pairs_compared": loops.pairs_checked,
        "pairs_inconsistent": loops.conflicts,
        "trusted": loops.trusted,
        "down_weighted": int((weights < 0.5).sum()),
        "residual_m": _quantiles(np.hypot(res[:, 0], res[:, 1])),
        "residual_rad": _quantiles(np.abs(res[:, 2])),
    }


def consistency_report(
    times: ArrayLike, sensor_poses: ArrayLike, batch: ScanBatch
) -> dict[str, Any]:
    """The self-consistency of a run (:func:`probmap.metrics.consistency.map_consistency`) on
    the batch's scans at ``sensor_poses`` (one per scan of the batch, map frame): the share of
    the walls its visits saw that other visits saw as open space, in all and per visit (times
    in seconds from the first scan). A figure, not yet a verdict: the threshold that tells a
    fold from doors and people is still to be measured on more logs."""
    from probmap.metrics.consistency import map_consistency

    t = np.asarray(times, dtype=np.float64)
    n = len(t)
    c = map_consistency(
        t, sensor_poses, np.asarray(batch.ranges)[:n],
        np.asarray(batch.angles) if np.ndim(batch.angles) == 1 else np.asarray(batch.angles)[:n],
        float(batch.max_range), visit_length=VISIT_LENGTH,
    )  # fmt: skip
    t0 = float(t[0]) if n else 0.0
    return {
        "share": c.share,
        "visit_length_m": VISIT_LENGTH,
        "visits": [
            {
                "start_s": v.start - t0,
                "end_s": v.end - t0,
                "occupied": v.occupied,
                "contradicted": v.contradicted,
            }
            for v in c.visits
        ],
        "pairs": [
            {"wall_visit": q.wall, "open_visit": q.open, "cells": q.cells, "box_m": list(q.box)}
            for q in c.pairs
        ],
    }


#: Least contradicted cells (0.1 m each: 2 m of wall) of a doubt (:func:`doubts_of`).
DOUBT_CELLS = 20


def doubts_of(report: dict[str, Any]) -> list[dict[str, Any]]:
    """Where and when a graph-SLAM map may be wrong, from its report (``local`` and
    ``consistency``, see :func:`slam_grid`); empty when nothing is in doubt.

    - ``"walls_in_open_space"``: visit A saw at least :data:`DOUBT_CELLS` cells (2 m) of its
      walls where visit B saw open space, B's own walls are contradicted by at least as many
      cells too, and the two visits are not consecutive. A fold or a wrong loop closure
      misplaces two visits against each other, so both see contradictions. A door or a person
      that moved contradicts one visit only; consecutive visits share their surroundings
      moments apart, so what differs between them is mostly the world changing. Measured:
      Freiburg 079 folded (0.54 m) 2 places; Intel, the Intel bag, Freiburg 079 mapped right
      none (also Intel's first 200 and 400 s); the hospital 9, at 594-653 s and 3450-3830 s,
      where its sparse scans are known to mislead local SLAM.
    - ``"untracked"``: lidar-only SLAM scans that matched nothing (placed by the
      constant-velocity prediction alone), in spans of scans less than 5 s apart.

    Each entry holds its times in seconds from the first scan; a place also its cells and
    ``box_m = [x_min, y_min, x_max, y_max]``, metres in the map frame.
    """
    out: list[dict[str, Any]] = []
    cons = report.get("consistency") or {}
    visits = cons.get("visits", [])
    for q in cons.get("pairs", []):
        a, b = visits[q["wall_visit"]], visits[q["open_visit"]]
        if (
            q["cells"] >= DOUBT_CELLS
            and b["contradicted"] >= DOUBT_CELLS
            and abs(q["wall_visit"] - q["open_visit"]) > 1
        ):
            out.append({
                "kind": "walls_in_open_space",
                "walls_seen_s": [a["start_s"], a["end_s"]],
                "open_space_seen_s": [b["start_s"], b["end_s"]],
                "cells": q["cells"],
                "box_m": q["box_m"],
            })  # fmt: skip
    lost = (report.get("local") or {}).get("untracked_s", [])
    spans: list[list[float]] = []
    for t in lost:
        if spans and t - spans[-1][1] < 5.0:
            spans[-1][1] = t
        else:
            spans.append([t, t])
    for lo, hi in spans:
        n = sum(1 for t in lost if lo <= t <= hi)
        out.append({"kind": "untracked", "start_s": lo, "end_s": hi, "scans": n})
    return out


def doubt_line(doubts: list[dict[str, Any]], prefix: str | os.PathLike[str]) -> str | None:
    """One line that says where the map may be wrong (:func:`doubts_of`), or None."""
    if not doubts:
        return None
    places = [d for d in doubts if d["kind"] == "walls_in_open_space"]
    lost = [d for d in doubts if d["kind"] == "untracked"]
    parts = []
    if places:
        d = places[0]
        w, o = d["walls_seen_s"], d["open_space_seen_s"]
        more = f" and {len(places) - 1} more place(s)" if len(places) > 1 else ""
        parts.append(
            f"walls seen at t = {w[0]:.0f}-{w[1]:.0f} s lie in open space seen at "
            f"t = {o[0]:.0f}-{o[1]:.0f} s ({d['cells'] / 10:.1f} m of wall{more}: a fold or a "
            f"wrong loop closure; red boxes in {prefix}.plot.png)"
        )
    if lost:
        n = sum(d["scans"] for d in lost)
        parts.append(
            f"{n} scan(s) without odometry matched nothing (t = {lost[0]['start_s']:.0f}"
            f"-{lost[-1]['end_s']:.0f} s)"
        )
    return "the map may be wrong: " + "; ".join(parts) + f" (see {prefix}.report.json)"
