"""Grid SLAM from a raw laser log or a ROS bag, end to end: read, run graph SLAM (or the RBPF),
write the map files, the trajectory, the pose graph and a picture.

The core (:mod:`probmap.slam.laser.submap_slam`) never reads or writes files; this module does, and the
CLI (``probmap slam grid``) only parses options and prints what it returns.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._atomic import atomic_outputs, atomic_write
from probmap.grid.occupancy import OccupancyGrid

if TYPE_CHECKING:
    from probmap.slam.laser.rbpf import RbpfConfig, RbpfResult

__all__ = [
    "SESSION_NAME",
    "SubmapSlamRun",
    "load_laser_log",
    "run_graph_slam",
    "slam_graph_log",
    "slam_log",
    "write_graph_slam",
    "write_trajectory",
]

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
    slam : object
        The :class:`~probmap.slam.laser.submap_slam.SubmapSlam` (its pose graph is written as g2o).
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
    slam: Any
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
    end_time: float | None = None,
    bag_options: dict[str, Any] | None = None,
    skip_bad_lines: bool = False,
) -> Any:
    """The scans graph SLAM runs on: :func:`probmap.datasets.open_scans` (a raw CARMEN log, a
    ROS 1/2 bag or a registry name; float32 ranges) and the checks graph SLAM needs.

    ``laser_poses`` are the laser's odometry poses (the laser pose fields of a raw CARMEN log;
    a bag's scans posed through tf in the odometry frame, topics and frames guessed as
    ``probmap map`` does) and ``robot_poses`` the robot's. ``end_time`` keeps the first
    ``end_time`` seconds.

    Raises
    ------
    DatasetError
        Unreadable or malformed input (naming the file and line), or no usable reading.
    ValueError
        A log without odometry (every pose the same) or with fewer than two scans.
    """
    batch = _open_laser_scans(path, "corrected", end_time, bag_options, skip_bad_lines)
    _require_odometry(path, batch)
    return batch


def _open_laser_scans(
    path: str | os.PathLike[str],
    poses: str,
    end_time: float | None,
    bag_options: dict[str, Any] | None,
    skip_bad_lines: bool,
) -> Any:
    """:func:`probmap.datasets.open_scans` as both grid SLAMs read a log: float32 ranges, the
    scans posed as ``poses`` says (``"corrected"`` or ``"odometry"``)."""
    from probmap.datasets.scans import open_scans

    return open_scans(
        path,
        poses=poses,
        dtype=np.float32,
        skip_bad_lines=skip_bad_lines,
        bag_options=bag_options,
        end_time=end_time,
    )


def _require_odometry(path: object, batch: Any) -> None:
    """Refuse what no grid SLAM can run on: fewer than two scans, or no odometry."""
    if len(batch.times) < 2:
        raise ValueError(f"{path}: grid SLAM needs at least 2 scans, found {len(batch.times)}")
    laser = np.asarray(batch.laser_poses)
    if not np.isfinite(laser).all():
        raise ValueError(f"{path}: the scans' odometry poses are not finite")
    if np.all(laser == laser[0]):
        raise ValueError(
            f"{path}: no odometry (every scan has the same pose); grid SLAM needs "
            "odometry to predict the motion between scans"
        )


def run_graph_slam(
    batch: Any,
    config: Any = None,
    *,
    progress: Callable[[int, int], None] | None = None,
    observer: Any = None,
    stop: Callable[[], bool] | None = None,
    resume: Any = None,
    save_session: str | os.PathLike[str] | None = None,
) -> SubmapSlamRun:
    """Run :class:`~probmap.slam.laser.submap_slam.SubmapSlam` over a scan batch (see
    :func:`load_laser_log`) and build the final map.

    ``observer``, when given, is called after every scan as ``observer(index, slam, ranges,
    angles)`` (the live view: :class:`probmap.viz.live.GraphSlamObserver`); if it has a
    ``finish`` method, that is called with the finished run.

    ``stop``, when given, is asked before every scan; once it returns True the run ends there
    as if the log ended: the graph is optimized and the map built from the scans so far
    (``SubmapSlamRun.interrupted``). The CLI's Ctrl-C handler sets it, so that an interrupted
    run still writes what it mapped. Stopping between scans keeps the state consistent, which
    an exception raised inside a scan's update would not.

    ``resume`` continues a saved run (:func:`~probmap.pipelines.sessions.load_session`) with this batch, in the same odometry
    frame (the rest of a log, or a log that carries on where the saved one stopped); the
    result then covers every scan of the session, and the earlier scans' robot poses use this
    batch's first mounting offset (a robot's laser does not move). ``save_session`` writes the
    run's state before it is finished, to be resumed later (a pickle: load only your own).
    """
    from probmap._memory import release_freed_memory
    from probmap.geometry.se2 import between, compose, inverse, wrap_angle
    from probmap.slam.laser.submap_slam import SubmapSlam, SubmapSlamConfig

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
    else:
        slam = SubmapSlam(cfg, max_range=float(batch.max_range))
    earlier = len(slam.scan_times)  # scans of the session before this batch
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
        slam.add_scan(times[i], r, a, laser[i])
        if observer is not None:
            observer(i, slam, r, a)
        if i % 200 == 199 or i == n - 1:
            peak = max(peak, slam.memory_bytes())
            release_freed_memory()  # finished submaps' grids and evicted max-grids
        if progress is not None and (i % 20 == 19 or i == n - 1):
            progress(i + 1, n)  # often enough for a steady rate (and ETA) in the bar
    if n < n_total:  # stopped early: the scans it got to
        times, mount = times[:n], mount[:n]
    if earlier:  # a resumed session: the result covers all of its scans
        times = np.concatenate([np.asarray(slam.scan_times[:earlier]), times])
        mount = np.concatenate([np.repeat(mount[:1], earlier, axis=0), mount])
    if save_session is not None:
        from probmap.pipelines.sessions import save_session as _save

        _save(slam, save_session)
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


def slam_graph_log(
    path: str | os.PathLike[str],
    config: Any = None,
    *,
    end_time: float | None = None,
    progress: Callable[[int, int], None] | None = None,
    bag_options: dict[str, Any] | None = None,
) -> SubmapSlamRun:
    """:func:`load_laser_log` then :func:`run_graph_slam`."""
    batch = load_laser_log(path, end_time=end_time, bag_options=bag_options)
    return run_graph_slam(batch, config, progress=progress)


def slam_log(
    path: str | os.PathLike[str],
    config: RbpfConfig | None = None,
    *,
    end_time: float | None = None,
    progress: Callable[[int, int], None] | None = None,
    skip_bad_lines: bool = False,
    readings: Callable[[Any], None] | None = None,
    bag_options: dict[str, Any] | None = None,
) -> RbpfResult:
    """Read a raw CARMEN log, a ROS 1/2 bag or a registry name
    (:func:`probmap.datasets.open_scans`) and run :func:`~probmap.slam.laser.rbpf.run_rbpf`
    on its front-laser scans.

    ``end_time`` keeps the scans of the first ``end_time`` seconds only; ``skip_bad_lines``
    skips and counts malformed or implausible lines instead of failing; ``bag_options`` a
    bag's topics and frames (guessed when not given). ``readings``, when given, is called with
    the :class:`~probmap.datasets.validate.ReadingReport` of the scans used.
    """
    from probmap.geometry.se2 import between
    from probmap.slam.laser.rbpf import run_rbpf

    batch = _open_laser_scans(path, "odometry", end_time, bag_options, skip_bad_lines)
    times = np.asarray(batch.times, dtype=np.float64)
    angles = np.asarray(batch.angles, dtype=np.float64)
    robot = np.asarray(batch.robot_poses, dtype=np.float64)
    laser = np.asarray(batch.laser_poses, dtype=np.float64)
    mount = between(robot[0], laser[0])
    if readings is not None:
        readings(batch.readings)
    return run_rbpf(
        times, np.asarray(batch.ranges), angles, robot, float(batch.max_range), config,
        mount=mount, progress=progress,
        beams=np.asarray(batch.beams) if angles.ndim == 2 else None,
    )  # fmt: skip


def write_trajectory(path: str | os.PathLike[str], times: ArrayLike, poses: ArrayLike) -> Path:
    """Write ``time,x,y,theta`` rows atomically (timestamps with microseconds)."""
    t = np.asarray(times, dtype=np.float64)
    p = np.asarray(poses, dtype=np.float64)
    with atomic_write(path, "w") as f:
        f.write("time,x,y,theta\n")
        for ti, (x, y, th) in zip(t, p, strict=True):
            f.write(f"{ti:.6f},{x:.6f},{y:.6f},{th:.6f}\n")
    return Path(path)


def write_graph_slam(prefix: str | os.PathLike[str], run: SubmapSlamRun) -> list[Path]:
    """Write ``PREFIX.yaml/.pgm/.npz/.png`` (the map), ``PREFIX.trajectory.csv`` (robot pose
    at every scan time), ``PREFIX.g2o`` (the optimized pose graph, laser poses) and
    ``PREFIX.plot.png`` (map, trajectory and accepted closures, axes in metres),
    all-or-nothing (a missing folder is created). Returns the paths written."""
    from probmap.datasets.g2o import write_pose_graph_g2o
    from probmap.grid.io import save_map
    from probmap.viz.laser_slam import save_graph_slam_figure

    prefix = Path(prefix)
    with atomic_outputs():
        files = list(save_map(prefix, run.grid))
        files.append(write_trajectory(f"{prefix}.trajectory.csv", run.times, run.poses))
        g = run.slam.graph
        files.append(
            write_pose_graph_g2o(f"{prefix}.g2o", g.poses, g.edges, g.measurements, g.information)
        )
        files.append(save_graph_slam_figure(f"{prefix}.plot.png", run, title=prefix.name))
    return files
