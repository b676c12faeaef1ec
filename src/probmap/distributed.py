"""Occupancy grid mapping of many logs on a Dask cluster: increments per task, a tree sum.

The log-odds update of Table 9.1 adds ``inverse_sensor_model - l0`` to a cell for every scan that
sees it, so without clamping the map is ``l0`` plus a sum over scans, and sums split across
machines. Every task here reads a share of the scans (a log, or a chunk of one long log) and
counts, per cell, how many scans hit it and how many crossed it, on a tile-aligned window of the
common cell lattice (cell ``(i, j)`` covers ``[i r, (i+1) r) x [j r, (j+1) r)`` for every task).
Counts are integers, so the tree reduction that sums them is exact and independent of the order
in which the partial sums meet. The prior and the clamping are applied once, at the end:

    l_i = clip(l0 + n_hit,i (l_hit - l0) + n_free,i (l_miss - l0), l_min, l_max)

Where this differs from sequential mapping
------------------------------------------
Sequential mapping (:class:`~probmap.grid.occupancy.OccupancyGrid`) clamps after *every* update.
Clamping at the end gives the same value in a cell whenever no prefix of its updates, in any
order, can leave ``[l_min, l_max]``: that holds when the cell received updates of one sign only
(clipping a monotone sequence once or at every step is the same), or when
``l0 + n_hit (l_hit - l0) <= l_max`` and ``l0 + n_free (l_miss - l0) >= l_min`` (every partial
sum lies between those two). Elsewhere both values lie in ``[l_min, l_max]`` and differ by at
most ``l_max - l_min``; :func:`clamping_bound` gives this bound per cell (0 where the map is
exact). Apart from clamping, the two differ only by float32 rounding (the sequential grid rounds
to float32 after every update, the distributed one once) and, as any two grids with different
origins do, in the cell of a point lying within rounding error (about 1e-15 cells) of a cell
boundary: ``floor((x - origin) / r)`` is evaluated with each window's own origin, as it is with
the sequential grid's origin after each growth. Recorded poses practically never fall there;
simulated ones on round coordinates do.

For a single log the default is the exact sequential semantics (one task runs
:func:`probmap.pipelines.map_log`); ``mode="increments"`` splits it into chunks instead.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from probmap.grid.occupancy import (
    InverseSensorModel,
    OccupancyGrid,
    ScanStats,
    effective_clear_range,
)
from probmap.grid.spec import GridSpec
from probmap.pipelines import MappingConfig, MappingResult

if TYPE_CHECKING:
    from probmap.datasets.carmen import LogShare
    from probmap.datasets.records import ScanBatch


class DistributedMappingError(RuntimeError):
    """Some inputs could not be mapped. ``result`` holds the map of those that were (or None)."""

    def __init__(self, message: str, result: DistributedMappingResult | None) -> None:
        super().__init__(message)
        self.result = result


@dataclass(frozen=True)
class DistributedOptions:
    """How the work is split over the cluster.

    Parameters
    ----------
    mode : {"auto", "sequential", "increments"}
        ``"sequential"``: one task maps one log with clamping after every update (exact
        sequential semantics; a single log only). ``"increments"``: tasks count updates and a
        tree reduction sums them (clamping at the end). ``"auto"``: sequential for one log with
        ``chunks == 1``, increments otherwise.
    chunks : int
        Tasks per log: each log is read once and its scans split into this many contiguous
        chunks (``>= 1``). Chunking by whole scans keeps the once-per-scan rule exact.
    tile : int
        Task windows start and end on multiples of ``tile`` cells of the common lattice.
    fan_in : int
        Partial sums merged per reduction task (``>= 2``).
    retries : int
        Times Dask retries a failed task before reporting it (a killed worker also reschedules).
    """

    mode: str = "auto"
    chunks: int = 1
    tile: int = 64
    fan_in: int = 4
    retries: int = 2

    def __post_init__(self) -> None:
        if self.mode not in ("auto", "sequential", "increments"):
            raise ValueError(
                f"mode must be 'auto', 'sequential' or 'increments', got {self.mode!r}"
            )
        if self.chunks < 1:
            raise ValueError(f"chunks must be >= 1, got {self.chunks}")
        if self.tile < 1:
            raise ValueError(f"tile must be >= 1 cells, got {self.tile}")
        if self.fan_in < 2:
            raise ValueError(f"fan_in must be >= 2, got {self.fan_in}")
        if self.retries < 0:
            raise ValueError(f"retries must be >= 0, got {self.retries}")


@dataclass(frozen=True)
class IncrementGrid:
    """Update counts of a share of the scans on a window of the common cell lattice.

    Parameters
    ----------
    resolution : float
        Cell side in metres.
    cell0 : tuple of int
        ``(ix0, iy0)``: lattice index of the window's cell ``[0, 0]``; its lower-left corner is
        at ``(ix0 r, iy0 r)`` metres in the world frame.
    hits, frees : ndarray of uint16 or int32, shape (H, W)
        Scans that hit the cell (endpoint or obstacle thickness) and scans whose beams crossed
        it, indexed ``[iy, ix]``. A task's own counts are uint16 when it integrated fewer than
        65,536 scans (a cell changes at most once per scan, so they cannot overflow; half the
        bytes to ship), int32 otherwise and in every sum. The log-odds increment is
        ``hits (l_hit - l0) + frees (l_miss - l0)``.
    stats : ScanStats
        Counts of the scans integrated.
    skipped_lines : int
        Malformed log lines skipped while reading them (``skip_bad_lines``).
    """

    resolution: float
    cell0: tuple[int, int]
    hits: NDArray[np.integer[Any]]
    frees: NDArray[np.integer[Any]]
    stats: ScanStats
    skipped_lines: int = 0

    @property
    def spec(self) -> GridSpec:
        """Geometry of the window (origin on the common lattice)."""
        r = self.resolution
        return GridSpec(r, (self.cell0[0] * r, self.cell0[1] * r), self.hits.shape)

    @classmethod
    def empty(cls, resolution: float) -> IncrementGrid:
        """No scans, no cells."""
        z = np.zeros((0, 0), dtype=np.int32)
        return cls(float(resolution), (0, 0), z, z.copy(), ScanStats(0, 0, 0, 0, 0, 0))

    def merge(self, other: IncrementGrid) -> IncrementGrid:
        """The sum of two increment grids on the union of their windows (exact: integers)."""
        if self.resolution != other.resolution:
            raise ValueError(
                f"cannot merge grids of resolution {self.resolution} and {other.resolution}"
            )
        parts = [g for g in (self, other) if g.hits.size]
        if not parts:
            return IncrementGrid(
                self.resolution,
                self.cell0,
                self.hits,
                self.frees,
                self.stats + other.stats,
                self.skipped_lines + other.skipped_lines,
            )
        x0 = min(g.cell0[0] for g in parts)
        y0 = min(g.cell0[1] for g in parts)
        x1 = max(g.cell0[0] + g.hits.shape[1] for g in parts)
        y1 = max(g.cell0[1] + g.hits.shape[0] for g in parts)
        hits = np.zeros((y1 - y0, x1 - x0), dtype=np.int32)
        frees = np.zeros_like(hits)
        for g in parts:
            oy, ox = g.cell0[1] - y0, g.cell0[0] - x0
            h, w = g.hits.shape
            hits[oy : oy + h, ox : ox + w] += g.hits
            frees[oy : oy + h, ox : ox + w] += g.frees
        return IncrementGrid(
            self.resolution,
            (x0, y0),
            hits,
            frees,
            self.stats + other.stats,
            self.skipped_lines + other.skipped_lines,
        )

    def cropped(self, margin: int = 2) -> IncrementGrid:
        """The counts trimmed to the observed cells plus ``margin`` cells (as
        :meth:`OccupancyGrid.cropped`), on the same lattice; a window without observed cells is
        returned as is."""
        seen = (self.hits > 0) | (self.frees > 0)
        rows = np.nonzero(seen.any(axis=1))[0]
        cols = np.nonzero(seen.any(axis=0))[0]
        if len(rows) == 0:
            return self
        h, w = seen.shape
        y0, y1 = max(int(rows[0]) - margin, 0), min(int(rows[-1]) + 1 + margin, h)
        x0, x1 = max(int(cols[0]) - margin, 0), min(int(cols[-1]) + 1 + margin, w)
        return replace(
            self,
            cell0=(self.cell0[0] + x0, self.cell0[1] + y0),
            hits=self.hits[y0:y1, x0:x1].copy(),
            frees=self.frees[y0:y1, x0:x1].copy(),
        )

    def log_odds(self, config: MappingConfig) -> NDArray[np.float32]:
        """Final log odds: prior plus increments, clamped once (see the module notes), (H, W)."""
        return self._final(config)[0]

    def _final(self, config: MappingConfig) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
        from probmap.grid import _kernels

        l0, d_hit, d_free, l_min, l_max = _levels(config)
        lo = np.empty(self.hits.shape, dtype=np.float32)
        seen = np.empty(self.hits.shape, dtype=np.bool_)
        if lo.size:
            _kernels.counts_to_log_odds(
                self.hits, self.frees, l0, d_hit, d_free, l_min, l_max, lo, seen
            )
        return lo, seen

    def to_grid(self, config: MappingConfig) -> OccupancyGrid:
        """The occupancy grid these counts describe, cropped to the observed cells."""
        lo, seen = self._final(config)
        grid = OccupancyGrid.from_log_odds(
            self.spec, lo, p0=config.p0, clamp=config.clamp, observed=seen, model=_model(config)
        )
        return grid.cropped()


def _model(config: MappingConfig) -> InverseSensorModel:
    return InverseSensorModel(config.p_hit, config.p_miss, config.thickness, config.max_clear_range)


def _levels(config: MappingConfig) -> tuple[float, float, float, float, float]:
    from probmap.grid.logodds import logit

    l0 = float(logit(config.p0))
    model = _model(config)
    return (
        l0,
        model.l_hit - l0,
        model.l_miss - l0,
        float(logit(config.clamp[0])),
        float(logit(config.clamp[1])),
    )


def clamping_bound(increments: IncrementGrid, config: MappingConfig) -> NDArray[np.float64]:
    """Per-cell bound on ``|distributed - sequential|`` log odds due to the clamping order.

    0 where no ordering of the cell's updates can reach a clamp (updates of one sign only, or
    ``l0 + n_hit d_hit <= l_max`` and ``l0 + n_free d_free >= l_min``); ``l_max - l_min``
    elsewhere (both maps lie in the clamp interval). Float32 rounding is not included: it adds
    at most a few units in the last place per update. Shape (H, W) of ``increments``.
    """
    l0, d_hit, d_free, l_min, l_max = _levels(config)
    hi = l0 + increments.hits * max(d_hit, 0.0) + increments.frees * max(d_free, 0.0)
    lo = l0 + increments.hits * min(d_hit, 0.0) + increments.frees * min(d_free, 0.0)
    one_sign = (increments.hits == 0) | (increments.frees == 0)
    if d_hit * d_free >= 0:  # both updates push the same way: monotone sequences
        one_sign = np.ones_like(one_sign)
    exact = one_sign | ((hi <= l_max) & (lo >= l_min))
    return np.where(exact, 0.0, l_max - l_min)


# ------------------------------------------------------------------ task bodies (run on workers)
_STAMPS = threading.local()


def _scratch_stamps(shape: tuple[int, int], n_scans: int) -> tuple[NDArray[np.int32], int]:
    """A per-thread stamp array of ``shape`` reused across tasks, and the first of ``n_scans``
    fresh stamp ids.

    The once-per-scan rule needs a stamp per cell that no earlier scan left equal to the current
    scan's id. Ids only grow within a process, so the buffer never needs clearing between tasks
    (it is cleared only when the ids would overflow int32): a worker touches warm memory instead
    of faulting in a new array per task, which measured 7 % of a task's time.
    """
    size = shape[0] * shape[1]
    buf: NDArray[np.int32] | None = getattr(_STAMPS, "buf", None)
    nxt: int = getattr(_STAMPS, "next", 1)
    if buf is None or buf.size < size:
        buf = np.zeros(max(size, 0 if buf is None else 2 * buf.size), dtype=np.int32)
        nxt = 1
    if nxt + n_scans >= np.iinfo(np.int32).max:
        buf[:] = 0
        nxt = 1
    _STAMPS.buf, _STAMPS.next = buf, nxt + n_scans
    return buf[:size].reshape(shape), nxt


def integrate_increments(
    poses: NDArray[np.float64],
    ranges: NDArray[np.floating[Any]],
    angles: NDArray[np.float64],
    max_range: float,
    config: MappingConfig,
    *,
    tile: int = 64,
) -> IncrementGrid:
    """Count the updates of a batch of scans (Table 9.1 without prior or clamping).

    Parameters
    ----------
    poses : ndarray, shape (S, 3)
        Sensor poses ``(x, y, theta)`` in the world frame (metres, radians).
    ranges : ndarray, shape (S, B)
        Ranges in metres; NaN/inf/non-positive readings are dropped, ``>= max_range`` means no
        return.
    angles : ndarray, shape (B,) or (S, B)
        Beam angles in the sensor frame, radians.
    max_range : float
        The sensor's maximum range in metres.
    config : MappingConfig
        Resolution and inverse sensor model (prior and clamp are not used here).
    tile : int
        The window is aligned to multiples of ``tile`` cells of the common lattice.

    Returns
    -------
    IncrementGrid
        Exactly the updates :meth:`OccupancyGrid.integrate_scans` would apply, one per cell
        and scan, with the hit winning over free space within a scan.
    """
    from probmap.grid import _kernels

    P = np.ascontiguousarray(poses, dtype=np.float64)
    R = np.ascontiguousarray(ranges, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or R.ndim != 2 or R.shape[0] != P.shape[0]:
        raise ValueError(f"poses must be (S, 3) and ranges (S, B), got {P.shape} and {R.shape}")
    if not np.isfinite(P).all():
        bad = int(np.nonzero(~np.isfinite(P).all(axis=1))[0][0])
        raise ValueError(f"poses must be finite numbers; pose {bad} is {P[bad].tolist()}")
    A = np.asarray(angles, dtype=np.float64)
    shared = A.ndim == 1
    A = np.ascontiguousarray(A[None, :] if shared else A)
    if A.shape[-1] != R.shape[1] or (not shared and A.shape[0] != R.shape[0]):
        raise ValueError(f"angles shape {np.shape(angles)} does not match ranges {R.shape}")
    if not np.isfinite(A).all():
        raise ValueError("angles must be finite")
    if not max_range > 0.0:
        raise ValueError(f"max_range must be > 0 m, got {max_range}")
    res = float(config.resolution)
    if P.shape[0] == 0:
        return IncrementGrid.empty(res)
    model = _model(config)
    clear = model.max_clear_range
    clear_range = effective_clear_range(clear, max_range)
    # window: every pose and endpoint plus one cell, rounded out to whole tiles
    box = np.empty(4)
    _kernels.scan_bounds(P, R, A, shared, float(max_range), clear_range, model.thickness, box)
    ix0 = (math.floor(box[0] / res) - 1) // tile * tile
    iy0 = (math.floor(box[2] / res) - 1) // tile * tile
    ix1 = -((-(math.floor(box[1] / res) + 2)) // tile) * tile
    iy1 = -((-(math.floor(box[3] / res) + 2)) // tile) * tile
    shape = (iy1 - iy0, ix1 - ix0)
    n = P.shape[0]
    dtype = np.uint16 if n <= np.iinfo(np.uint16).max else np.int32
    hits = np.zeros(shape, dtype=dtype)
    frees = np.zeros(shape, dtype=dtype)
    stamp, sid0 = _scratch_stamps(shape, n)
    counts = np.zeros(4, dtype=np.int64)
    _kernels.count_scans(
        hits,
        frees,
        stamp,
        sid0,
        ix0 * res,
        iy0 * res,
        res,
        P,
        R,
        A,
        shared,
        float(max_range),
        clear_range,
        model.thickness,
        counts,
    )
    stats = ScanStats(
        n, int(R.size), int(counts[0]), int(counts[1]), int(counts[2]), int(counts[3])
    )
    return IncrementGrid(res, (int(ix0), int(iy0)), hits, frees, stats)


def _load(path: str, config: MappingConfig) -> ScanBatch:
    from probmap.datasets.carmen import load_scans

    return load_scans(
        path, poses=config.poses, max_range=config.max_range, skip_bad_lines=config.skip_bad_lines
    )


def _max_range(batch: ScanBatch, config: MappingConfig) -> float:
    return float(config.max_range if config.max_range is not None else batch.max_range)


def _batch_task(
    batch: ScanBatch | None, max_range: float, config: MappingConfig, tile: int
) -> IncrementGrid:
    """Increments of one batch of scans (None: a share of a log without scans)."""
    if batch is None:
        return IncrementGrid.empty(float(config.resolution))
    inc = integrate_increments(
        batch.laser_poses, batch.ranges, batch.angles, max_range, config, tile=tile
    )
    return replace(inc, skipped_lines=int(batch.skipped_lines))


def _log_task(path: str, config: MappingConfig, tile: int) -> IncrementGrid:
    """A whole log: read, then count its updates."""
    batch = _load(path, config)
    return _batch_task(batch, _max_range(batch, config), config, tile)


def _split_task(path: str, n_shares: int) -> list[LogShare]:
    """Read (decompress) a log once and cut it into shares of lines (parsed by other tasks)."""
    from probmap.datasets.carmen import split_log

    return split_log(path, n_shares)


def _pick(shares: list[LogShare], k: int) -> LogShare | None:
    return shares[k] if k < len(shares) else None  # a log with fewer laser lines than shares


def _parse_task(share: LogShare | None, config: MappingConfig) -> ScanBatch | None:
    """The scans of one share, parsed where the share is (in parallel with the others)."""
    from probmap.datasets.carmen import load_share

    if share is None:
        return None
    return load_share(
        share, poses=config.poses, max_range=config.max_range, skip_bad_lines=config.skip_bad_lines
    )


def _share_max_range(batch: ScanBatch | None) -> float | None:
    """A parsed share's maximum range (runs where the share is: only a number travels)."""
    return None if batch is None else float(batch.max_range)


def _max_range_task(path: str, *ranges: float | None) -> float:
    """The whole log's maximum range (the smallest of its scans', as for one batch)."""
    from probmap.errors import DatasetError

    found = [r for r in ranges if r is not None]
    if not found:
        raise DatasetError("no FLASER/ROBOTLASER1 scans in the log", path=path)
    return float(min(found))


def _merge_task(*parts: IncrementGrid) -> IncrementGrid:
    out = parts[0]
    for p in parts[1:]:
        out = out.merge(p)
    return out


def _crop_task(total: IncrementGrid) -> IncrementGrid:
    return total.cropped()


def tree_sum(parts: Sequence[IncrementGrid], fan_in: int = 4) -> IncrementGrid:
    """Sum increment grids the way the cluster does, level by level (for tests and one machine)."""
    if not parts:
        raise ValueError("nothing to sum")
    level = list(parts)
    while len(level) > 1:
        level = [_merge_task(*level[i : i + fan_in]) for i in range(0, len(level), fan_in)]
    return level[0]


# ------------------------------------------------------------------ results and the pipeline
@dataclass(frozen=True)
class DistributedMappingResult:
    """A map built on a cluster, which inputs went into it and which did not.

    ``increments`` is None in sequential mode. ``failed`` pairs each input that could not be
    mapped with the error its task raised (after Dask's retries).
    """

    grid: OccupancyGrid
    stats: ScanStats
    mode: str
    mapped: tuple[Path, ...]
    failed: tuple[tuple[Path, str], ...]
    tasks: int
    workers: int
    seconds: float
    skipped_lines: int = 0
    increments: IncrementGrid | None = None

    def as_mapping_result(self) -> MappingResult:
        """The result in the shape :func:`probmap.pipelines.write_map` writes."""
        return MappingResult(
            grid=self.grid,
            stats=self.stats,
            parse_seconds=0.0,
            map_seconds=self.seconds,
            skipped_lines=self.skipped_lines,
            extra={"tasks": float(self.tasks), "workers": float(self.workers)},
        )


def _resolve_mode(n_logs: int, options: DistributedOptions) -> str:
    if options.mode == "sequential":
        if n_logs != 1 or options.chunks != 1:
            raise ValueError(
                "mode='sequential' maps one log in one task; use mode='increments' for "
                f"{n_logs} logs or chunks={options.chunks}"
            )
        return "sequential"
    if options.mode == "auto" and n_logs == 1 and options.chunks == 1:
        return "sequential"
    return "increments"


def _error_text(exc: BaseException | None) -> str:
    if exc is None:
        return "unknown error"
    msg = str(exc) or exc.__class__.__name__
    if isinstance(exc, OSError) and exc.filename and str(exc.filename) not in msg:
        msg = f"{exc.filename}: {msg}"
    return msg


_TRIM_VAR = "MALLOC_TRIM_THRESHOLD_"


def local_cluster(n_workers: int, **kwargs: Any) -> Any:
    """Start a Dask ``LocalCluster`` of ``n_workers`` single-threaded worker processes, set up
    for mapping tasks (what ``map_logs_distributed(workers=N)`` starts).

    Differs from Dask's defaults in one setting: worker processes are spawned without Dask's
    ``MALLOC_TRIM_THRESHOLD_=65536``. Setting that variable turns off glibc's adaptive mmap
    threshold, so every array of a task (a few MB of counts and scan arrays) is mapped fresh
    from the OS and page-faulted in; measured on 48 simulated logs with 2 workers, mapping
    tasks took 8 % longer and the reduction's sums 4x longer with it. Workers of a cluster you
    start yourself (``--scheduler``) can get the same by unsetting it in their environment
    (``distributed.nanny.pre-spawn-environ``). ``kwargs`` go to ``LocalCluster``.

    Returns
    -------
    distributed.LocalCluster
        Close it when done (``with local_cluster(2) as cluster: ...``).
    """
    import dask
    from distributed import LocalCluster

    if n_workers < 1:
        raise ValueError(f"n_workers must be >= 1, got {n_workers}")
    options: dict[str, Any] = {
        "threads_per_worker": 1,
        "processes": True,
        "dashboard_address": ":0",
    }
    options.update(kwargs)
    # an earlier cluster's nanny in this process may have exported Dask's value; workers
    # inherit this process's environment, so it is lifted while they are spawned
    inherited = os.environ.get(_TRIM_VAR)
    if inherited == "65536":
        del os.environ[_TRIM_VAR]
    try:
        with dask.config.set({f"distributed.nanny.pre-spawn-environ.{_TRIM_VAR}": None}):
            return LocalCluster(n_workers=n_workers, **options)
    finally:
        if inherited == "65536":
            os.environ[_TRIM_VAR] = inherited


def map_logs_distributed(
    paths: Sequence[str | os.PathLike[str]],
    config: MappingConfig | None = None,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool | Callable[[int, int], None] = True,
    options: DistributedOptions | None = None,
    allow_partial: bool = False,
    client: Any = None,
) -> DistributedMappingResult:
    """Map many CARMEN logs (or chunks of one) on a Dask cluster and sum the increments.

    Parameters
    ----------
    paths : sequence of path-like
        The logs; all are mapped into one grid in the world frame of their poses.
    config : MappingConfig, optional
        Mapping parameters, as for :func:`probmap.pipelines.map_log`.
    workers : int, optional
        Start a local cluster of this many single-threaded worker processes (default: one per
        CPU). Ignored with ``scheduler`` or ``client``.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``) to use instead.
    progress : bool or callable
        True shows Dask's progress bar in the terminal; a callable is called as
        ``progress(done, total)`` as input tasks finish; False shows nothing.
    options : DistributedOptions, optional
        Mode, chunks per log, tile size, reduction fan-in, retries.
    allow_partial : bool
        If false (default) any input that fails raises :class:`DistributedMappingError`; if
        true the map of the other inputs is returned with ``failed`` filled in.
    client : distributed.Client, optional
        An existing client (it is left open).

    Returns
    -------
    DistributedMappingResult

    Raises
    ------
    ImportError
        Dask is not installed (``pip install 'probmap[distributed]'``).
    DistributedMappingError
        Some (or all) inputs could not be mapped; the message names each file and its error.
    """
    try:
        from distributed import Client
    except ImportError as exc:  # pragma: no cover - dask is in the test extra
        raise ImportError(
            "distributed mapping needs Dask: pip install 'probmap[distributed]'"
        ) from exc
    cfg = config or MappingConfig()
    opts = options or DistributedOptions()
    files = [Path(p) for p in paths]
    if not files:
        raise ValueError("no input logs given")
    for f in files:
        if not f.is_file():
            raise FileNotFoundError(f"{f}: no such log file")
    if workers is not None and workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    mode = _resolve_mode(len(files), opts)
    cluster = None
    own_client = client is None
    t0 = time.perf_counter()
    if client is None:
        if scheduler is not None:
            client = Client(scheduler)
        else:
            cluster = local_cluster(workers or os.cpu_count() or 1)
            client = Client(cluster)
    try:
        n_workers = len(client.scheduler_info()["workers"])
        return _run(client, files, cfg, opts, mode, progress, allow_partial, n_workers, t0)
    finally:
        if own_client:
            client.close()
        if cluster is not None:
            cluster.close()


def _run(
    client: Any,
    files: list[Path],
    cfg: MappingConfig,
    opts: DistributedOptions,
    mode: str,
    progress: bool | Callable[[int, int], None],
    allow_partial: bool,
    n_workers: int,
    t0: float,
) -> DistributedMappingResult:
    from distributed import wait

    from probmap.pipelines import map_log

    retries = opts.retries
    if mode == "sequential":
        fut = client.submit(map_log, str(files[0]), cfg, retries=retries, pure=False)
        _wait(client, [fut], progress)
        if fut.status != "finished":
            msg = _error_text(fut.exception())
            raise DistributedMappingError(f"could not map {files[0]}: {msg}", None)
        res: MappingResult = fut.result()
        return DistributedMappingResult(
            grid=res.grid,
            stats=res.stats,
            mode=mode,
            mapped=(files[0],),
            failed=(),
            tasks=1,
            workers=n_workers,
            seconds=time.perf_counter() - t0,
            skipped_lines=res.skipped_lines,
        )
    # the whole graph goes in at once (nothing waits on the client): per log, one task, or a
    # read task that cuts its lines into shares, then a parse and an integrating task per share
    # per log: every future of the log (a failure in any fails the log) and its increments
    per_log: list[tuple[list[Any], list[Any]]] = []
    shown: list[Any] = []  # the tasks the progress counts (not the picks, which only index)
    for f in files:
        if opts.chunks == 1:
            inc = client.submit(_log_task, str(f), cfg, opts.tile, retries=retries, pure=False)
            per_log.append(([inc], [inc]))
            shown.append(inc)
            continue
        # one task reads (decompresses) the log and cuts its lines into shares; the shares are
        # parsed and integrated in parallel, each where it was picked
        split = client.submit(_split_task, str(f), opts.chunks, retries=retries, pure=False)
        picks = [client.submit(_pick, split, k, retries=retries) for k in range(opts.chunks)]
        parsed = [client.submit(_parse_task, s, cfg, retries=retries) for s in picks]
        futs = [split, *picks, *parsed]
        if cfg.max_range is None:  # the smallest of the scans' maxima, as for the whole log
            each = [client.submit(_share_max_range, b, retries=retries) for b in parsed]
            mr = client.submit(_max_range_task, str(f), *each, retries=retries)
            futs.extend([*each, mr])
        else:
            mr = float(cfg.max_range)
        incs = [client.submit(_batch_task, b, mr, cfg, opts.tile, retries=retries) for b in parsed]
        per_log.append((futs + incs, incs))
        shown.extend([split, *parsed, *incs])
    _wait(client, shown, progress)
    wait([fut for fs, _ in per_log for fut in fs])
    mapped: list[Path] = []
    failed: list[tuple[Path, str]] = []
    parts: list[Any] = []
    n_tasks = sum(len(fs) for fs, _ in per_log)
    for f, (fs, incs) in zip(files, per_log, strict=True):
        bad = next((fut for fut in fs if fut.status != "finished"), None)
        if bad is not None:
            failed.append((f, _error_text(bad.exception())))
            continue
        mapped.append(f)
        parts.extend(incs)
    if not parts:
        msgs = "; ".join(f"{f}: {m}" for f, m in failed)
        raise DistributedMappingError(f"no input could be mapped ({msgs})", None)
    # tree reduction: fan_in partial sums per task, level by level
    level = parts
    while len(level) > 1:
        level = [
            client.submit(_merge_task, *level[i : i + opts.fan_in], retries=retries)
            for i in range(0, len(level), opts.fan_in)
        ]
        n_tasks += len(level)
    # trimmed where the sum is, so that only the observed part travels to this process
    total: IncrementGrid = client.submit(_crop_task, level[0], retries=retries).result()
    n_tasks += 1
    grid = total.to_grid(cfg)
    result = DistributedMappingResult(
        grid=grid,
        stats=total.stats,
        mode=mode,
        mapped=tuple(mapped),
        failed=tuple(failed),
        tasks=n_tasks,
        workers=n_workers,
        seconds=time.perf_counter() - t0,
        skipped_lines=total.skipped_lines,
        increments=total,
    )
    if failed and not allow_partial:
        lines = "; ".join(f"{f}: {m}" for f, m in failed)
        raise DistributedMappingError(
            f"{len(failed)} of {len(files)} inputs could not be mapped ({lines}); "
            f"mapped: {', '.join(str(p) for p in mapped)}",
            result,
        )
    return result


def _wait(client: Any, futures: list[Any], progress: bool | Callable[[int, int], None]) -> None:
    from distributed import as_completed, wait

    if progress is True:
        from distributed.diagnostics.progressbar import progress as dask_progress

        dask_progress(futures)
        wait(futures)
    elif callable(progress):
        done = 0
        for _ in as_completed(futures):
            done += 1
            progress(done, len(futures))
    else:
        wait(futures)


# ------------------------------------------------------------------ semantic grids
@dataclass(frozen=True)
class SemanticIncrements:
    """Summed log-odds increments of a semantic grid's updates on a window of the lattice.

    Parameters
    ----------
    resolution : float
        Cell side in metres.
    cell0 : tuple of int
        Lattice index ``(ix0, iy0)`` of the window's cell ``[0, 0]``.
    delta : ndarray of float64, shape (H, W, K)
        Sum over the scans of each update ``inverse term - prior term`` (no clamping).
    observed : ndarray of bool, shape (H, W)
        Cells updated at least once.
    stats : ScanStats
        Counts of the scans integrated.

    Notes
    -----
    The evidence of a semantic update is a real number (class distributions, pooled endpoints),
    so the increments are float64 sums rather than counts: the tree sum is exact up to float64
    rounding (about 1e-13 of the magnitude), far below the final float32 storage. Clamping is
    per class: the result lies within ``l_max[k] - l_min[k]`` of the sequential grid in every
    cell and class and equals it (to rounding) wherever no partial sum reaches a clamp.
    """

    resolution: float
    cell0: tuple[int, int]
    delta: NDArray[np.float64]
    observed: NDArray[np.bool_]
    stats: ScanStats

    @property
    def spec(self) -> GridSpec:
        """Geometry of the window (origin on the common lattice)."""
        r = self.resolution
        return GridSpec(r, (self.cell0[0] * r, self.cell0[1] * r), self.observed.shape)

    def merge(self, other: SemanticIncrements) -> SemanticIncrements:
        """The sum of two increment grids on the union of their windows."""
        if self.resolution != other.resolution or self.delta.shape[2] != other.delta.shape[2]:
            raise ValueError("cannot merge semantic increments of different resolution or classes")
        parts = [g for g in (self, other) if g.observed.size]
        if not parts:
            return replace(self, stats=self.stats + other.stats)
        x0 = min(g.cell0[0] for g in parts)
        y0 = min(g.cell0[1] for g in parts)
        x1 = max(g.cell0[0] + g.observed.shape[1] for g in parts)
        y1 = max(g.cell0[1] + g.observed.shape[0] for g in parts)
        delta = np.zeros((y1 - y0, x1 - x0, self.delta.shape[2]))
        seen = np.zeros((y1 - y0, x1 - x0), dtype=bool)
        for g in parts:
            oy, ox = g.cell0[1] - y0, g.cell0[0] - x0
            h, w = g.observed.shape
            delta[oy : oy + h, ox : ox + w] += g.delta
            seen[oy : oy + h, ox : ox + w] |= g.observed
        return SemanticIncrements(self.resolution, (x0, y0), delta, seen, self.stats + other.stats)

    def to_grid(self, classes: Sequence[str], **grid_kwargs: Any) -> Any:
        """The :class:`~probmap.grid.semantic.SemanticGrid` (``grid_kwargs``: its prior, clamp,
        model, colors): prior plus increments, clamped once per class."""
        from probmap.grid.semantic import SemanticGrid

        ref = SemanticGrid(classes, resolution=self.resolution, **grid_kwargs)
        lo = np.clip(ref.l_prior + self.delta, ref.l_min, ref.l_max)
        return SemanticGrid.from_log_odds(
            classes,
            self.spec,
            lo.astype(np.float32),
            observed=self.observed,
            scans=self.stats.scans,
            **grid_kwargs,
        )


def integrate_semantic_increments(
    scans: Any,
    *,
    resolution: float,
    tile: int = 64,
    start: int = 0,
    stop: int | None = None,
    **grid_kwargs: Any,
) -> SemanticIncrements:
    """Sum the updates of labelled scans ``start:stop`` without prior or clamping.

    Parameters
    ----------
    scans : probmap.grid.semantic_io.LabelledScans
        Poses (S, 3), ranges (S, B), angles, labels (S, B) or probabilities (S, B, K).
    resolution : float
        Cell side in metres.
    tile : int
        The window is aligned to multiples of ``tile`` cells of the common lattice.
    grid_kwargs
        :class:`~probmap.grid.semantic.SemanticGrid` arguments (prior, model; a clamp is
        accepted and ignored here).

    Returns
    -------
    SemanticIncrements
        The updates :meth:`SemanticGrid.integrate_scans` applies (same kernel, same
        once-per-scan rule and endpoint pooling), accumulated in float64 without clamping.
    """
    from probmap.grid import _kernels
    from probmap.grid.semantic import SemanticGrid

    sl = slice(start, stop)
    poses = np.ascontiguousarray(scans.poses[sl], dtype=np.float64)
    ranges = np.ascontiguousarray(scans.ranges[sl], dtype=np.float64)
    angles = np.asarray(scans.angles, dtype=np.float64)
    angles = angles if angles.ndim == 1 else angles[sl]
    kwargs = {k: v for k, v in grid_kwargs.items() if k != "clamp"}
    K = len(scans.classes) - 1
    if poses.shape[0] == 0:
        z = np.zeros((0, 0), dtype=bool)
        return SemanticIncrements(
            float(resolution), (0, 0), np.zeros((0, 0, K)), z, ScanStats(0, 0, 0, 0, 0, 0)
        )
    probe = SemanticGrid(scans.classes, resolution=resolution, **kwargs)
    model = probe.model
    clear = model.max_clear_range
    mr = float(scans.max_range)
    clear_range = effective_clear_range(clear, mr)
    A = np.ascontiguousarray(angles[None, :] if angles.ndim == 1 else angles)
    if not np.isfinite(poses).all():
        raise ValueError("poses must be finite numbers")
    if ranges.ndim != 2 or A.shape[-1] != ranges.shape[1]:
        raise ValueError(f"angles shape {angles.shape} does not match ranges {ranges.shape}")
    box = np.empty(4)
    _kernels.scan_bounds(poses, ranges, A, angles.ndim == 1, mr, clear_range, model.thickness, box)
    res = float(resolution)
    ix0 = (math.floor(box[0] / res) - 1) // tile * tile
    iy0 = (math.floor(box[2] / res) - 1) // tile * tile
    ix1 = -((-(math.floor(box[1] / res) + 2)) // tile) * tile
    iy1 = -((-(math.floor(box[3] / res) + 2)) // tile) * tile
    spec = GridSpec(res, (ix0 * res, iy0 * res), (iy1 - iy0, ix1 - ix0))
    grid = SemanticGrid(scans.classes, resolution=res, spec=spec, fixed=True, **kwargs)
    # the grid's own validation, evidence and kernel, on float64 zeros with no clamping: the
    # cells then hold the sums of the increments
    grid._lo = np.zeros((*spec.shape, K), dtype=np.float64)
    grid.l_min = np.full(K, -math.inf)
    grid.l_max = np.full(K, math.inf)
    stats = grid.integrate_scans(
        poses,
        ranges,
        angles,
        labels=None if scans.labels is None else scans.labels[sl],
        probabilities=None if scans.probabilities is None else scans.probabilities[sl],
        max_range=mr,
    )
    delta = np.asarray(grid._lo, dtype=np.float64)
    return SemanticIncrements(res, (int(ix0), int(iy0)), delta, grid.observed, stats)


def _semantic_task(
    path: str, k: int, n_chunks: int, resolution: float, tile: int, grid_kwargs: dict[str, Any]
) -> SemanticIncrements:
    from probmap.grid.semantic_io import read_labelled_scans

    scans = read_labelled_scans(path)
    n = len(scans)
    return integrate_semantic_increments(
        scans,
        resolution=resolution,
        tile=tile,
        start=(k * n) // n_chunks,
        stop=((k + 1) * n) // n_chunks,
        **grid_kwargs,
    )


def _merge_semantic(*parts: SemanticIncrements) -> SemanticIncrements:
    out = parts[0]
    for p in parts[1:]:
        out = out.merge(p)
    return out


@dataclass(frozen=True)
class SemanticMappingResult:
    """A semantic map built on a cluster, and which inputs went into it."""

    grid: Any
    stats: ScanStats
    mapped: tuple[Path, ...]
    failed: tuple[tuple[Path, str], ...]
    tasks: int
    seconds: float
    increments: SemanticIncrements


def map_labelled_distributed(
    paths: Sequence[str | os.PathLike[str]],
    *,
    resolution: float = 0.05,
    client: Any,
    chunks: int = 1,
    tile: int = 64,
    fan_in: int = 4,
    retries: int = 2,
    progress: bool | Callable[[int, int], None] = False,
    allow_partial: bool = False,
    **grid_kwargs: Any,
) -> SemanticMappingResult:
    """Map labelled-scan files (:func:`probmap.grid.semantic_io.write_labelled_scans`) on a
    Dask cluster into one :class:`~probmap.grid.semantic.SemanticGrid`.

    Every file is read by ``chunks`` tasks, each integrating its share of the scans; the
    increments are summed by a tree reduction and the prior and per-class clamps applied at the
    end (see :class:`SemanticIncrements`). The files must share their class names.
    ``grid_kwargs`` are the grid's prior, clamp, model and colors. Failures are reported as by
    :func:`map_logs_distributed` (:class:`DistributedMappingError` unless ``allow_partial``).
    """
    from probmap.grid.semantic_io import read_labelled_scans

    files = [Path(p) for p in paths]
    if not files:
        raise ValueError("no input files given")
    for f in files:
        if not f.is_file():
            raise FileNotFoundError(f"{f}: no such labelled-scan file")
    if chunks < 1:
        raise ValueError(f"chunks must be >= 1, got {chunks}")
    t0 = time.perf_counter()
    classes: tuple[str, ...] | None = None
    per_file = []
    for f in files:
        per_file.append(
            [
                client.submit(
                    _semantic_task,
                    str(f),
                    k,
                    chunks,
                    resolution,
                    tile,
                    grid_kwargs,
                    retries=retries,
                    pure=False,
                )  # fmt: skip
                for k in range(chunks)
            ]
        )
    _wait(client, [fut for fs in per_file for fut in fs], progress)
    mapped: list[Path] = []
    failed: list[tuple[Path, str]] = []
    parts: list[Any] = []
    for f, fs in zip(files, per_file, strict=True):
        bad = next((fut for fut in fs if fut.status != "finished"), None)
        if bad is not None:
            failed.append((f, _error_text(bad.exception())))
            continue
        names = read_labelled_scans(f).classes
        if classes is not None and names != classes:
            failed.append((f, f"classes {list(names)} differ from {list(classes)}"))
            continue
        classes = names
        mapped.append(f)
        parts.extend(fs)
    n_tasks = len(files) * chunks
    if not parts or classes is None:
        msgs = "; ".join(f"{f}: {m}" for f, m in failed)
        raise DistributedMappingError(f"no input could be mapped ({msgs})", None)
    level = parts
    while len(level) > 1:
        level = [
            client.submit(_merge_semantic, *level[i : i + fan_in], retries=retries)
            for i in range(0, len(level), fan_in)
        ]
        n_tasks += len(level)
    total: SemanticIncrements = level[0].result()
    result = SemanticMappingResult(
        grid=total.to_grid(classes, **grid_kwargs),
        stats=total.stats,
        mapped=tuple(mapped),
        failed=tuple(failed),
        tasks=n_tasks,
        seconds=time.perf_counter() - t0,
        increments=total,
    )
    if failed and not allow_partial:
        lines = "; ".join(f"{f}: {m}" for f, m in failed)
        raise DistributedMappingError(
            f"{len(failed)} of {len(files)} inputs could not be mapped ({lines})", None
        )
    return result
