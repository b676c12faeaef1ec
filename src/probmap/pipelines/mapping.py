"""Occupancy grid mapping with known poses, end to end: a log or bag in, a map and its files out
(Table 9.1 over every scan; MAP mapping of a whole log, Table 9.3, in the same shape)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from probmap._checks import require_at_least
from probmap.grid.occupancy import InverseSensorModel, OccupancyGrid, ScanStats

if TYPE_CHECKING:
    from probmap.mapping.map_mapping import MapMappingConfig, SweepRecord


__all__ = [
    "DemoResult",
    "MappingConfig",
    "MappingResult",
    "map_log",
    "map_log_map",
    "run_mapping_demo",
    "write_map",
]


@dataclass(frozen=True)
class MappingConfig:
    """Parameters of occupancy grid mapping with known poses.

    Parameters
    ----------
    resolution : float
        Cell size in metres.
    max_range : float or None
        Sensor maximum range in metres; None takes the log's own (PARAM or the reader's rule).
    poses : str
        ``"corrected"``: the scans' own laser poses (GMapping-corrected in a corrected log);
        ``"odometry"``: the robot's odometry composed with the laser offset.
    p_hit, p_miss, thickness, max_clear_range
        The inverse sensor model (see :class:`~probmap.grid.occupancy.InverseSensorModel`).
        A max-range reading means "no return" (CARMEN logs store 81.9 m), not "free for 80 m":
        by default it clears 10 m; ``None`` clears up to the maximum range.
    p0 : float
        Prior occupancy.
    clamp : tuple of float
        Clamping bounds as probabilities.
    skip_bad_lines : bool
        Skip and count malformed log lines instead of failing.
    chunk : int
        Scans integrated per kernel call (progress granularity).
    """

    resolution: float = 0.05
    max_range: float | None = None
    poses: str = "corrected"
    p_hit: float = 0.7
    p_miss: float = 0.4
    thickness: float = 0.0
    max_clear_range: float | None = 10.0
    p0: float = 0.5
    clamp: tuple[float, float] = (0.12, 0.97)
    skip_bad_lines: bool = False
    chunk: int = 1000

    def __post_init__(self) -> None:
        if self.poses not in ("corrected", "odometry"):
            raise ValueError(f"poses must be 'corrected' or 'odometry', got {self.poses!r}")
        if not self.resolution > 0:
            raise ValueError(f"resolution must be > 0 m, got {self.resolution}")
        if self.max_range is not None and not self.max_range > 0:
            raise ValueError(f"max_range must be > 0 m, got {self.max_range}")
        if self.chunk < 1:
            raise ValueError("chunk must be >= 1")

    def make_grid(self) -> OccupancyGrid:
        """The empty grid this configuration describes."""
        model = InverseSensorModel(self.p_hit, self.p_miss, self.thickness, self.max_clear_range)
        return OccupancyGrid(self.resolution, p0=self.p0, clamp=self.clamp, model=model)


@dataclass(frozen=True)
class MappingResult:
    """A built map, what went into it and how long it took."""

    grid: OccupancyGrid
    stats: ScanStats
    parse_seconds: float
    map_seconds: float
    write_seconds: float = 0.0
    files: tuple[Path, ...] = ()
    skipped_lines: int = 0
    extra: dict[str, float] = field(default_factory=dict)
    readings: Any = None
    """The :class:`~probmap.datasets.validate.ReadingReport` of the log (None for a simulation)."""
    trajectory: Any = None
    """Sensor poses (S, 3) of the scans, drawn on ``PREFIX.plot.png`` (None: no trajectory)."""
    source: str | None = None
    """What was mapped (the log's file name), the title of ``PREFIX.plot.png``."""
    interrupted: bool = False
    """The run was stopped (``map_log(stop=)``) before the last scan: the map holds the scans
    before it (``stats.scans`` of ``scans_total``)."""
    scans_total: int = 0
    """Scans of the log (0: not recorded)."""
    pose_source: str = ""
    """What placed the scans (:attr:`probmap.datasets.records.ScanBatch.pose_source`):
    ``"odometry"`` means the map is built from raw odometry and drifts."""


def map_log(
    path: str | os.PathLike[str],
    config: MappingConfig | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
    bag_options: dict[str, Any] | None = None,
    observer: Callable[..., None] | None = None,
    observe_every: int = 20,
    stop: Callable[[], bool] | None = None,
) -> MappingResult:
    """Build an occupancy grid from a laser log with known poses (Table 9.1).

    Parameters
    ----------
    path : path-like or str
        A CARMEN log (plain, .gz or .bz2), a ROS 1/2 bag or a registered laser dataset's name
        (read by :func:`probmap.datasets.open_scans`).
    config : MappingConfig, optional
        Mapping parameters.
    progress : callable, optional
        Called as ``progress(done, total)`` after each chunk of scans.
    bag_options : dict, optional
        A bag's topics and frames (``scan_topic``, ``odom_topic``, ``fixed_frame``,
        ``laser_frame``); guessed when not given.
    observer : callable, optional
        A live view (:class:`probmap.viz.live.MappingObserver`), called as
        ``observer(done, grid, trajectory, ranges, angles, max_range)`` after every
        ``observe_every`` scans: the grid so far, the sensor poses (done, 3) so far and the
        newest scan's ranges (B,) and angles (B,) (metres, radians). It must not change the
        grid. The chunks then end at its calls: the scans go in in the same order, but the
        grid grows in other steps, so its origin may differ by rounding (1e-15 m).
    observe_every : int
        Scans between calls of ``observer`` (>= 1).
    stop : callable, optional
        Asked before each chunk of scans; when it returns True mapping ends there (Ctrl-C in
        the CLI) and the result holds the scans so far (``interrupted``).

    Returns
    -------
    MappingResult
    """
    require_at_least("observe_every", observe_every, 1)
    cfg = config or MappingConfig()
    t0 = time.perf_counter()
    batch = _open(path, cfg, bag_options)
    t1 = time.perf_counter()
    max_range = float(batch.max_range)
    report = batch.readings
    grid = cfg.make_grid()
    stats = ScanStats(0, 0, 0, 0, 0, 0)
    n = len(batch.times)
    poses = np.asarray(batch.laser_poses)
    angles = np.asarray(batch.angles)
    # chunks end at the observer's calls too (the scans are integrated in the same order)
    step = cfg.chunk if observer is None else min(cfg.chunk, observe_every)
    done = 0
    for start in range(0, n, step):
        if stop is not None and stop():
            break
        end = min(start + step, n)
        ang = angles if angles.ndim == 1 else angles[start:end]
        stats = stats + grid.integrate_scans(
            poses[start:end], batch.ranges[start:end], ang, max_range=max_range
        )
        done = end
        if observer is not None:
            scan_angles = angles if angles.ndim == 1 else angles[end - 1]
            observer(end, grid, poses[:end], batch.ranges[end - 1], scan_angles, max_range)
        if progress is not None:
            progress(end, n)
    grid = grid.cropped()
    t2 = time.perf_counter()
    return MappingResult(
        grid=grid,
        stats=_without_padding(stats, batch, done),
        parse_seconds=t1 - t0,
        map_seconds=t2 - t1,
        skipped_lines=int(getattr(batch, "skipped_lines", 0)),
        readings=report,
        trajectory=poses[:done],
        source=Path(path).name,
        interrupted=done < n,
        scans_total=n,
        pose_source=str(getattr(batch, "pose_source", "")),
    )


def _open(
    path: str | os.PathLike[str], cfg: MappingConfig, bag_options: dict[str, Any] | None
) -> Any:
    """The scans of ``path`` as every mapping pipeline reads them (one log, one rule)."""
    from probmap.datasets.scans import open_scans

    return open_scans(
        path,
        poses=cfg.poses,
        max_range=cfg.max_range,
        skip_bad_lines=cfg.skip_bad_lines,
        bag_options=bag_options,
    )


def _without_padding(stats: ScanStats, batch: Any, scans: int | None = None) -> ScanStats:
    """``stats`` with the padding of short scans (NaN cells of a batch of mixed beam counts)
    counted neither as beams nor as dropped readings (over the first ``scans`` scans; all by
    default)."""
    from dataclasses import replace

    ranges = np.asarray(batch.ranges)[:scans]
    pad = int(ranges.size - int(np.asarray(batch.beams)[:scans].sum()))
    if pad <= 0:
        return stats
    return replace(stats, beams=stats.beams - pad, dropped=max(0, stats.dropped - pad))


def write_map(
    prefix: str | os.PathLike[str],
    result: MappingResult,
    config: Any = None,
    *,
    command: str | None = None,
) -> MappingResult:
    """Write ``PREFIX.yaml``, ``.pgm``, ``.npz``, ``.png`` and the picture ``PREFIX.plot.png``
    (axes in metres, a scale bar, the input's name, the trajectory), and with ``config`` (the
    :class:`MappingConfig` the map was built with) ``PREFIX.config.yaml`` (with the probmap
    version, and ``command``, the command line, on its first line), all-or-nothing (creating a missing folder); returns the result with the files and
    the write time filled in."""
    from dataclasses import replace

    from probmap._atomic import atomic_outputs
    from probmap.grid.io import save_map
    from probmap.viz.maps import save_map_figure

    t0 = time.perf_counter()
    with atomic_outputs():  # a missing folder is created (and removed again on failure)
        files = list(save_map(prefix, result.grid))
        files.append(
            save_map_figure(
                f"{prefix}.plot.png", result.grid, trajectory=result.trajectory,
                title=result.source,
            )
        )  # fmt: skip
        if config is not None:
            from probmap.config import write_config

            files.append(write_config(f"{prefix}.config.yaml", config, command=command))
    return replace(
        result, files=tuple(Path(f) for f in files), write_seconds=time.perf_counter() - t0
    )


@dataclass(frozen=True)
class DemoResult:
    """What ``probmap demo`` built and how good it is against the ground truth."""

    mapping: MappingResult
    accuracy: float
    cells_classified: int
    scans: int


def run_mapping_demo(
    prefix: str | os.PathLike[str] | None = None,
    *,
    seed: int = 0,
    resolution: float = 0.05,
    config: MappingConfig | None = None,
    command: str | None = None,
) -> DemoResult:
    """Map the simulated floor plan (range noise, dropped beams) and score it against the truth.

    Accuracy is the fraction of observed cells whose trinary class at p = 0.5 matches the true
    map (see :func:`probmap.metrics.map.map_accuracy`). ``config`` (a :class:`MappingConfig`:
    resolution, inverse sensor model, prior, clamp) replaces ``resolution``; the configuration
    used (``MappingConfig(resolution=resolution)`` without one) is recorded as
    ``PREFIX.config.yaml`` with ``command`` on its first line; its log-reading fields (``max_range``, ``poses``,
    ``skip_bad_lines``) do not apply to the simulation.
    """
    from probmap.metrics.map import map_accuracy
    from probmap.sim.floorplan import simulate_laser_world

    t0 = time.perf_counter()
    world = simulate_laser_world(seed=seed, resolution=0.05, range_noise=0.02, dropout=0.01)
    t1 = time.perf_counter()
    if config is None:
        config = MappingConfig(resolution=resolution)
    grid = config.make_grid()
    stats = grid.integrate_scans(world.poses, world.ranges, world.angles, max_range=world.max_range)
    t2 = time.perf_counter()
    acc, n = map_accuracy(grid.classify(0.5, 0.5), grid.spec, world.truth, world.spec)
    result = MappingResult(
        grid, stats, t1 - t0, t2 - t1, trajectory=world.poses,
        source="probmap demo: simulated floor plan",
    )  # fmt: skip
    if prefix is not None:
        result = write_map(prefix, result, config, command=command)
    return DemoResult(result, acc, n, len(world.poses))


def map_log_map(
    path: str | os.PathLike[str],
    config: MappingConfig | None = None,
    progress: Callable[[SweepRecord], None] | None = None,
    *,
    map_config: MapMappingConfig | None = None,
    bag_options: dict[str, Any] | None = None,
) -> MappingResult:
    """MAP mapping of a laser log or bag, in the shape of :func:`probmap.pipelines.map_log`.

    ``config`` gives the resolution, pose source, maximum range, clamp and bad-line policy;
    ``map_config`` the MAP parameters (its resolution is replaced by ``config.resolution``);
    ``bag_options`` a bag's topics and frames. The input is read by
    :func:`probmap.datasets.open_scans` (a CARMEN log, a ROS 1/2 bag or a registry name).
    The binary map becomes an :class:`~probmap.grid.occupancy.OccupancyGrid` whose occupied
    cells hold ``logit(clamp[1])``, free observed cells ``logit(clamp[0])`` and unobserved
    cells the prior, so :func:`probmap.pipelines.write_map` writes the usual files.
    ``MappingResult.extra`` holds ``objective``, ``sweeps``, ``converged``,
    ``index_seconds``, ``sweep_seconds`` and ``objective_<k>`` per sweep.
    """
    from dataclasses import replace

    from probmap.grid.logodds import logit
    from probmap.mapping.map_mapping import MapMappingConfig, map_mapping

    cfg = config or MappingConfig(resolution=0.1)
    mcfg = replace(map_config or MapMappingConfig(), resolution=cfg.resolution)
    t0 = time.perf_counter()
    batch = _open(path, cfg, bag_options)
    t1 = time.perf_counter()
    max_range = float(batch.max_range)
    report = batch.readings
    res = map_mapping(
        np.asarray(batch.laser_poses), batch.ranges, np.asarray(batch.angles), max_range, mcfg,
        progress=progress,
    )  # fmt: skip
    t2 = time.perf_counter()
    lo = np.full(res.spec.shape, float(logit(cfg.p0)), dtype=np.float32)
    lo[res.observed] = float(logit(cfg.clamp[0]))
    lo[res.occupied] = float(logit(cfg.clamp[1]))
    grid = OccupancyGrid.from_log_odds(
        res.spec, lo, p0=cfg.p0, clamp=cfg.clamp, observed=res.observed | res.occupied
    )
    ranges = np.asarray(batch.ranges)
    n_total = int(np.asarray(batch.beams).sum())  # padding of short scans is no beam
    stats = ScanStats(
        scans=int(ranges.shape[0]),
        beams=n_total,
        hits=res.index.beams,
        max_range=res.index.max_range_beams,
        dropped=max(0, res.index.dropped - (int(ranges.size) - n_total)),
        cell_updates=res.index.entries,
    )
    extra = {
        "objective": res.objective,
        "sweeps": float(len(res.history) - 1),
        "converged": float(res.converged),
        "index_seconds": res.index_seconds,
        "sweep_seconds": res.sweep_seconds,
    }
    for r in res.history:
        extra[f"objective_{r.sweep}"] = r.objective
    return MappingResult(
        grid=grid,
        stats=stats,
        parse_seconds=t1 - t0,
        map_seconds=t2 - t1,
        skipped_lines=int(getattr(batch, "skipped_lines", 0)),
        extra=extra,
        readings=report,
        trajectory=np.asarray(batch.laser_poses),
        source=f"{Path(path).name} (MAP mapping)",
        pose_source=str(getattr(batch, "pose_source", "")),
    )
