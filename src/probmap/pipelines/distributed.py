"""Occupancy grid mapping of many logs on a Dask cluster: one task per log or share of a log,
counting its updates, and a tree sum of the counts.

The mathematics (why sums of counts give the sequential map, and where clamping makes them
differ) is in :mod:`probmap.grid.increments`. This module reads the logs where the workers are,
submits the tasks, reduces their sums and reports which inputs failed.

For a single log the default is the exact sequential semantics (one task runs
:func:`probmap.pipelines.map_log`); ``mode="increments"`` splits it into chunks instead.

Errors
------
A task whose input is bad (a malformed log, a missing file, a map that would exceed the grid's
size limit) fails the same way on every try, so it is not retried and its worker logs no
traceback: the task returns the error's message, which the pipeline reports once, naming the
file. Dask retries (``DistributedOptions.retries``) only what may pass on another try: a worker
that died, a task that ran out of memory.
"""

from __future__ import annotations

import functools
import os
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from probmap._checks import require_at_least, require_positive_finite
from probmap.grid.increments import (
    IncrementGrid,
    SemanticIncrements,
    clamping_bound,
    integrate_increments,
    integrate_semantic_increments,
    tree_sum,
)
from probmap.grid.occupancy import OccupancyGrid, ScanStats
from probmap.pipelines.mapping import MappingConfig, MappingResult

if TYPE_CHECKING:
    from probmap.datasets.carmen import LogShare
    from probmap.datasets.records import ScanBatch

__all__ = [
    "DistributedMappingError",
    "DistributedMappingResult",
    "DistributedOptions",
    "IncrementGrid",
    "SemanticIncrements",
    "SemanticMappingResult",
    "clamping_bound",
    "integrate_increments",
    "integrate_semantic_increments",
    "local_cluster",
    "map_labelled_distributed",
    "map_log_map_distributed",
    "map_logs_distributed",
    "tree_sum",
]


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
    worker_ttl : float
        Seconds a worker of the local cluster this starts may go without a heartbeat (a
        stalled process: stopped, swapped out, stuck in the kernel) before the scheduler
        restarts it and runs its tasks on another worker; a task whose workers keep dying
        this way fails the run with a message naming its input, never an indefinite hang.
        Dask enforces at least ten heartbeat intervals (5 s on a small cluster). A scheduler
        you run yourself (``scheduler``) uses its own ``distributed.scheduler.worker-ttl``.
    """

    mode: str = "auto"
    chunks: int = 1
    tile: int = 64
    fan_in: int = 4
    retries: int = 2
    worker_ttl: float = 60.0

    def __post_init__(self) -> None:
        if self.mode not in ("auto", "sequential", "increments"):
            raise ValueError(
                f"mode must be 'auto', 'sequential' or 'increments', got {self.mode!r}"
            )
        require_at_least("chunks", self.chunks, 1)
        if self.tile < 1:
            raise ValueError(f"tile must be >= 1 cells, got {self.tile}")
        if self.fan_in < 2:
            raise ValueError(f"fan_in must be >= 2, got {self.fan_in}")
        require_at_least("retries", self.retries, 0)
        require_positive_finite("worker_ttl", self.worker_ttl)


# ------------------------------------------------------------------ task bodies (run on workers)
@dataclass(frozen=True)
class _Failed:
    """A task's deterministic error, returned instead of raised: Dask does not retry it and the
    worker logs no traceback. Tasks that receive one pass it on."""

    message: str


#: Errors that a retry cannot cure: bad or missing input, a map over the size limit.
_DETERMINISTIC: tuple[type[BaseException], ...] = (ValueError, OSError, EOFError, LookupError)


def _task(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Wrap a task body: a :class:`_Failed` argument is passed on, a deterministic error is
    returned as :class:`_Failed` (its message naming the file); anything else raises, so that
    Dask retries it."""

    @functools.wraps(fn)
    def run(*args: Any) -> Any:
        for a in args:
            if isinstance(a, _Failed):
                return a
        try:
            return fn(*args)
        except _DETERMINISTIC as exc:
            return _Failed(_error_text(exc))

    return run


def _failed(fut: Any) -> str | None:
    """The error of a finished or failed future, or None; only a :class:`_Failed` result (a few
    bytes) is fetched, never a grid."""
    if fut.status != "finished":
        return _error_text(fut.exception())
    typ = fut.type
    if typ is _Failed or (isinstance(typ, str) and typ.endswith("_Failed")):
        return str(fut.result().message)
    return None


@_task
def _map_log_task(
    path: str, config: MappingConfig, bag_options: dict[str, Any] | None
) -> MappingResult:
    """One log mapped with the exact sequential semantics (clamping after every update)."""
    from probmap.pipelines.mapping import map_log

    return map_log(path, config, bag_options=bag_options)


@_task
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


@_task
def _log_task(
    path: str, config: MappingConfig, tile: int, bag_options: dict[str, Any] | None
) -> IncrementGrid:
    """A whole log (or bag): read as ``map_log`` reads it (refusing one without a usable
    reading), count its updates."""
    from probmap.pipelines.mapping import _open

    batch = _open(path, config, bag_options)
    return _batch_task(batch, float(batch.max_range), config, tile)


@_task
def _split_task(path: str, n_shares: int) -> list[LogShare]:
    """Read (decompress) a log once and cut it into shares of lines (parsed by other tasks)."""
    from probmap.datasets.carmen import split_log

    return split_log(path, n_shares)


@_task
def _pick(shares: list[LogShare], k: int) -> LogShare | None:
    return shares[k] if k < len(shares) else None  # a log with fewer laser lines than shares


@_task
def _parse_task(share: LogShare | None, config: MappingConfig) -> ScanBatch | None:
    """The scans of one share, parsed where the share is (in parallel with the others)."""
    from probmap.datasets.carmen import load_share

    if share is None:
        return None
    return load_share(
        share, poses=config.poses, max_range=config.max_range, skip_bad_lines=config.skip_bad_lines
    )


@_task
def _share_max_range(batch: ScanBatch | None) -> float | None:
    """A parsed share's maximum range (runs where the share is: only a number travels)."""
    return None if batch is None else float(batch.max_range)


@_task
def _share_readings(batch: ScanBatch | None) -> Any:
    """A parsed share's reading counts (a few numbers travel, not the scans)."""
    return None if batch is None else batch.readings


@_task
def _require_usable_task(path: str, *reports: Any) -> bool:
    """The whole log has at least one usable reading (else a DatasetError naming it)."""
    from probmap.datasets.validate import ReadingReport, require_usable

    total = ReadingReport()
    for r in reports:
        if r is not None:
            total = total + r
    require_usable(total, path)
    return True


@_task
def _max_range_task(path: str, *ranges: float | None) -> float:
    """The whole log's maximum range (the smallest of its scans', as for one batch)."""
    from probmap.errors import DatasetError

    found = [r for r in ranges if r is not None]
    if not found:
        raise DatasetError("no FLASER/ROBOTLASER1 scans in the log", path=path)
    return float(min(found))


@_task
def _share_top(batch: ScanBatch | None) -> tuple[float, int, float, int] | None:
    """A parsed share's two largest readings and their counts, when its log states no maximum
    range (runs where the share is: four numbers travel)."""
    from probmap.datasets.validate import top_readings

    if batch is None or batch.max_range_stated:
        return None
    return top_readings(batch.ranges, float(batch.max_range))


@_task
def _no_return_task(max_range: float, *tops: tuple[float, int, float, int] | None) -> float:
    """The whole log's no-return reading when it states no maximum range and its shares'
    readings show one (:func:`probmap.datasets.validate.no_return_from_tops`, as
    :func:`probmap.datasets.carmen.load_scans` infers it from the whole log), else
    ``max_range``."""
    from probmap.datasets.validate import no_return_from_tops

    found = no_return_from_tops(tops)
    return max_range if found is None or found.value >= max_range else found.value


@_task
def _merge_task(*parts: IncrementGrid) -> IncrementGrid:
    return tree_sum(parts, fan_in=max(len(parts), 2))


@_task
def _crop_task(total: IncrementGrid) -> IncrementGrid:
    return total.cropped()


# ------------------------------------------------------------------ results and the pipeline
# SemanticMappingResult repeats part of these fields: a shared base would put its fields first
# and so reorder the positional fields of both public result classes.
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
            source=", ".join(p.name for p in self.mapped[:3])
            + (f" and {len(self.mapped) - 3} more" if len(self.mapped) > 3 else ""),
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
    from probmap.errors import error_message

    if exc is None:
        return "unknown error"
    return error_message(exc)


def _named(path: Path, message: str) -> str:
    """``path: message``, unless the message names the file already."""
    return message if str(path) in message else f"{path}: {message}"


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

    require_at_least("n_workers", n_workers, 1)
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
    bag_options: dict[str, Any] | None = None,
) -> DistributedMappingResult:
    """Map many laser logs (or chunks of one) on a Dask cluster and sum the increments.

    Parameters
    ----------
    paths : sequence of path-like
        The logs, CARMEN (plain, .gz, .bz2) or ROS 1/2 bags, or registered laser datasets'
        names (resolved here, before any task: workers get the files' paths); all are mapped
        into one grid in the world frame of their poses.
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
    bag_options : dict, optional
        ROS bags' topic and frame options (``scan_topic``, ``odom_topic``, ``fixed_frame``,
        ``laser_frame``), as for :func:`probmap.pipelines.map_log`; every bag gets the same.
        A bag is read by one task (``chunks`` splits CARMEN logs only).

    Returns
    -------
    DistributedMappingResult

    Raises
    ------
    MissingExtraError
        (an ImportError) Dask is not installed (``pip install 'probmap[distributed]'``).
    FileNotFoundError, ValueError
        Before anything is submitted: a missing input, bag options without a bag, chunks of
        a bag, a bad option.
    DistributedMappingError
        Some (or all) inputs could not be mapped; the message names each file and its error,
        once (a bad input is not retried).
    """
    from probmap.datasets.ros.scans import is_bag
    from probmap.datasets.scans import resolve_log

    _require_dask()
    cfg = config or MappingConfig()
    opts = options or DistributedOptions()
    # registry names become their files here, where the data directory is known
    files = [resolve_log(p) if not Path(p).exists() else Path(p) for p in paths]
    if not files:
        raise ValueError("no input logs given")
    bags = [f for f in files if is_bag(f)]
    for f in files:
        if not (f.is_file() or f in bags):
            raise FileNotFoundError(f"{f}: no such log file")
    if bag_options and any(v not in (None, 0) for v in bag_options.values()):
        if len(bags) < len(files):
            other = next(f for f in files if f not in bags)
            raise ValueError(f"{other}: topic/frame options apply to ROS bags only")
    if bags and opts.chunks > 1:
        raise ValueError(
            f"{bags[0]}: a ROS bag is read by one task; chunks={opts.chunks} splits CARMEN "
            "logs only"
        )
    if workers is not None:
        require_at_least("workers", workers, 1)
    mode = _resolve_mode(len(files), opts)
    t0 = time.perf_counter()
    with _connected(client, workers, scheduler, opts.worker_ttl) as cl:
        n_workers = len(cl.scheduler_info()["workers"])
        return _run(cl, files, cfg, opts, mode, progress, allow_partial, n_workers, t0, bag_options)


def _require_dask() -> None:
    """Raise :class:`~probmap.errors.MissingExtraError` unless Dask's ``distributed`` is
    installed (checked before anything is read or started)."""
    from probmap.errors import MissingExtraError

    try:
        import distributed  # noqa: F401
    except ImportError as exc:  # pragma: no cover - dask is in the test extra
        raise MissingExtraError(
            "distributed mapping needs Dask: pip install 'probmap[distributed]'"
        ) from exc


@contextmanager
def _connected(
    client: Any, workers: int | None, scheduler: str | None, worker_ttl: float = 60.0
) -> Iterator[Any]:
    """``client``, or a client of the scheduler at ``scheduler``, or of a new local cluster of
    ``workers`` processes whose scheduler restarts a worker silent for ``worker_ttl`` seconds
    (closed again on exit; a given client is left open)."""
    from distributed import Client

    if client is not None:
        yield client
        return
    if scheduler is not None:
        with Client(scheduler) as cl:
            yield cl
        return
    ttl = {"worker_ttl": f"{worker_ttl}s"}
    with (
        local_cluster(workers or os.cpu_count() or 1, scheduler_kwargs=ttl) as cluster,
        Client(cluster) as cl,
    ):
        yield cl


@_task
def _map_log_map_task(
    path: str, config: MappingConfig, map_config: Any, bag_options: dict[str, Any] | None
) -> MappingResult:
    from probmap.pipelines.mapping import map_log_map

    return map_log_map(path, config, map_config=map_config, bag_options=bag_options)


def map_log_map_distributed(
    path: str | os.PathLike[str],
    config: MappingConfig | None = None,
    *,
    map_config: Any = None,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    bag_options: dict[str, Any] | None = None,
    retries: int = 2,
) -> MappingResult:
    """MAP mapping (:func:`probmap.pipelines.map_log_map`) of one log as one task on a Dask
    cluster: the sweeps of the MAP search depend on each other, so the log is not split, but
    the work runs where the cluster is (a bigger machine, ``--scheduler``). A bad input's error
    is raised once, as :class:`DistributedMappingError` naming the file.
    """
    from probmap.datasets.ros.scans import is_bag

    _require_dask()
    f = Path(path)
    if not (f.is_file() or is_bag(f)):
        raise FileNotFoundError(f"{f}: no such log file")
    cfg = config or MappingConfig()
    with _connected(client, workers, scheduler) as cl:
        fut = cl.submit(
            _map_log_map_task, str(f), cfg, map_config, bag_options, retries=retries, pure=False
        )
        result: MappingResult = _one_result(cl, fut, f, False)
    return result


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
    bag_options: dict[str, Any] | None,
) -> DistributedMappingResult:
    from distributed import wait

    retries = opts.retries
    if mode == "sequential":
        fut = client.submit(
            _map_log_task, str(files[0]), cfg, bag_options, retries=retries, pure=False
        )
        res: MappingResult = _one_result(client, fut, files[0], progress)
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
            inc = client.submit(
                _log_task, str(f), cfg, opts.tile, bag_options, retries=retries, pure=False
            )
            per_log.append(([inc], [inc]))
            shown.append(inc)
            continue
        # one task reads (decompresses) the log and cuts its lines into shares; the shares are
        # parsed and integrated in parallel, each where it was picked
        split = client.submit(_split_task, str(f), opts.chunks, retries=retries, pure=False)
        picks = [client.submit(_pick, split, k, retries=retries) for k in range(opts.chunks)]
        parsed = [client.submit(_parse_task, s, cfg, retries=retries) for s in picks]
        # the log as a whole must have a usable reading (a share alone need not)
        reports = [client.submit(_share_readings, b, retries=retries) for b in parsed]
        usable = client.submit(_require_usable_task, str(f), *reports, retries=retries)
        futs = [split, *picks, *parsed, *reports, usable]
        if cfg.max_range is None:  # the smallest of the scans' maxima, as for the whole log
            each = [client.submit(_share_max_range, b, retries=retries) for b in parsed]
            stated = client.submit(_max_range_task, str(f), *each, retries=retries)
            tops = [client.submit(_share_top, b, retries=retries) for b in parsed]
            mr = client.submit(_no_return_task, stated, *tops, retries=retries)
            futs.extend([*each, stated, *tops, mr])
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
        msg = _first_failure(fs)
        if msg is not None:
            failed.append((f, msg))
            continue
        mapped.append(f)
        parts.extend(incs)
    if not parts:
        raise DistributedMappingError(f"no input could be mapped ({_listed(failed)})", None)
    root, n_merges = _tree_reduce(client, _merge_task, parts, opts.fan_in, retries)
    n_tasks += n_merges
    # trimmed where the sum is, so that only the observed part travels to this process
    total = _summed(client.submit(_crop_task, root, retries=retries))
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
        raise DistributedMappingError(
            f"{len(failed)} of {len(files)} inputs could not be mapped ({_listed(failed)}); "
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


def _one_result(
    client: Any, fut: Any, path: Path, progress: bool | Callable[[int, int], None]
) -> Any:
    """The result of the one task ``fut`` that maps ``path``, once it is done; its error raises
    :class:`DistributedMappingError` naming the file."""
    _wait(client, [fut], progress)
    msg = _failed(fut)
    if msg is not None:
        raise DistributedMappingError(f"could not map {_named(path, msg)}", None)
    return fut.result()


def _first_failure(futures: list[Any]) -> str | None:
    """The error of the first of an input's futures that failed (:func:`_failed`), or None."""
    return next((m for m in map(_failed, futures) if m is not None), None)


def _listed(failed: list[tuple[Path, str]]) -> str:
    """The failed inputs and their errors for a message: ``path: error; path: error``."""
    return "; ".join(_named(f, m) for f, m in failed)


def _tree_reduce(
    client: Any, merge: Callable[..., Any], parts: list[Any], fan_in: int, retries: int
) -> tuple[Any, int]:
    """Tree reduction of the futures ``parts``: ``fan_in`` partial sums per ``merge`` task,
    level by level. Returns the root's future (``parts[0]`` for one part) and the number of
    merge tasks submitted."""
    level = parts
    n_tasks = 0
    while len(level) > 1:
        level = [
            client.submit(merge, *level[i : i + fan_in], retries=retries)
            for i in range(0, len(level), fan_in)
        ]
        n_tasks += len(level)
    return level[0], n_tasks


def _summed(fut: Any) -> Any:
    """The sum that ``fut`` (the top of a reduction) holds; a failed sum raises
    :class:`DistributedMappingError`."""
    total = fut.result()
    if isinstance(total, _Failed):
        raise DistributedMappingError(f"could not sum the increments: {total.message}", None)
    return total


@_task
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


@_task
def _merge_semantic(*parts: SemanticIncrements) -> SemanticIncrements:
    out = parts[0]
    for p in parts[1:]:
        out = out.merge(p)
    return out


# Part of DistributedMappingResult's fields (no mode, workers or skipped lines: labelled scans
# are .npz files mapped on a cluster only); a shared base would reorder the public fields.
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
    require_at_least("chunks", chunks, 1)
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
        msg = _first_failure(fs)
        if msg is not None:
            failed.append((f, msg))
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
        raise DistributedMappingError(f"no input could be mapped ({_listed(failed)})", None)
    root, n_merges = _tree_reduce(client, _merge_semantic, parts, fan_in, retries)
    n_tasks += n_merges
    total = _summed(root)
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
        raise DistributedMappingError(
            f"{len(failed)} of {len(files)} inputs could not be mapped ({_listed(failed)})", None
        )
    return result
