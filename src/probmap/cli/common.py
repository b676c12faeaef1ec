"""Helpers shared by CLI commands: one-line errors and non-zero exits, never tracebacks, and the
two-column summary table every command prints at the end."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import typer

if TYPE_CHECKING:
    from rich.console import Console


class CliError(Exception):
    """An error the CLI reports on one line."""


_INTERRUPTS_SAID = [0]


def say_interrupted(message: str) -> None:
    """Print the one ``interrupted: ...`` line of an interrupted command on stderr (every
    command words it alike: ``interrupted: nothing written`` or what was written)."""
    _INTERRUPTS_SAID[0] += 1
    typer.echo(message, err=True)


def interrupts_said() -> int:
    """How many ``interrupted: ...`` lines :func:`say_interrupted` printed in this process."""
    return _INTERRUPTS_SAID[0]


@contextmanager
def cli_errors() -> Iterator[None]:
    """Turn expected library errors into a one-line message on stderr and exit code 1 (a
    missing optional extra too: its message names what to install).

    SIGTERM (``timeout``, systemd, Docker, Slurm) is a Ctrl-C here: an interrupt that ends the
    command is one line, ``interrupted: nothing written`` (the outputs are all or none), or
    which files it had put in place, and exit code 130. Temporary files of killed runs that
    the command's writes removed (:func:`probmap._atomic.sweep_leftovers`) are named in one
    line at the end."""
    from probmap import _atomic
    from probmap.errors import MissingExtraError, error_message

    swept = len(_atomic.removed_leftovers)
    wrote = len(_atomic.written)
    try:
        with sigterm_as_ctrl_c():
            yield
    except (CliError, ValueError, OSError, EOFError, KeyError, MissingExtraError) as exc:
        typer.echo(f"error: {error_message(exc)}", err=True)
        raise typer.Exit(1) from None
    except KeyboardInterrupt:
        done = _atomic.written[wrote:]
        if done:
            names = ", ".join(str(p) for p in done[:3]) + (", ..." if len(done) > 3 else "")
            say_interrupted(f"interrupted: wrote {len(done)} file(s) before it: {names}")
        else:
            say_interrupted("interrupted: nothing written")
        raise typer.Exit(130) from None
    finally:
        gone = _atomic.removed_leftovers[swept:]
        if gone:
            names = ", ".join(str(p) for p in gone[:3]) + (", ..." if len(gone) > 3 else "")
            typer.echo(
                f"removed {len(gone)} temporary file(s) left by killed runs: {names}", err=True
            )


@contextmanager
def sigterm_as_ctrl_c() -> Iterator[None]:
    """While active (on the main thread), SIGTERM raises KeyboardInterrupt as Ctrl-C does, so
    that every command stops on it as on Ctrl-C (all outputs or none, one line). The previous
    handler is restored on exit."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextmanager
def bad_lines_quiet() -> Iterator[None]:
    """Inside: no :class:`~probmap.errors.BadLinesWarning` text on the terminal, the command's
    summary reports the skipped lines instead."""
    import warnings

    from probmap.errors import BadLinesWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BadLinesWarning)
        yield


def check_choice(option: str, value: str | None, choices: Iterable[str]) -> None:
    """Raise :class:`ValueError` unless ``value`` is one of ``choices`` or None (the option not
    given): ``--method must be 'graph' or 'rbpf', got 'x'``, one message form for every
    command's word options."""
    allowed = tuple(choices)
    if value is None or value in allowed:
        return
    words = [repr(c) for c in allowed]
    either = words[0] if len(words) == 1 else f"{', '.join(words[:-1])} or {words[-1]}"
    raise ValueError(f"{option} must be {either}, got {value!r}")


def resolve_config(cls: type, path: Any = None, overrides: dict[str, Any] | None = None) -> Any:
    """The configuration a command runs with: ``cls`` loaded from the YAML file ``path``
    (:func:`probmap.config.load_config`; the class defaults without one), then the options the
    user gave (``overrides`` whose value is not None) on top."""
    import dataclasses

    from probmap.config import load_config

    cfg = load_config(cls, path) if path is not None else cls()
    given = {k: v for k, v in (overrides or {}).items() if v is not None}
    return dataclasses.replace(cfg, **given) if given else cfg


def kernels_cached(*modules: str) -> bool:
    """Whether numba's on-disk cache holds compiled kernels of every one of ``modules``
    (dotted names of modules whose kernels use ``cache=True``): an index file
    ``<module>.<function>-<line>.py<ver>.nbi`` beside the module (or in ``NUMBA_CACHE_DIR``).
    Reads the file system only; imports neither numba nor the modules."""
    import importlib.util
    import os
    from pathlib import Path

    cache_dir = os.environ.get("NUMBA_CACHE_DIR")
    for name in modules:
        spec = importlib.util.find_spec(name)
        if spec is None or spec.origin is None:
            return False
        src = Path(spec.origin)
        folder = Path(cache_dir) if cache_dir else src.parent / "__pycache__"
        try:
            if not any(folder.glob(f"{src.stem}.*.nbi")) and not any(
                folder.rglob(f"{src.stem}.*.nbi")
            ):
                return False
        except OSError:
            return False
    return True


def note_first_compile(*modules: str) -> None:
    """Say on stderr that numba is compiling, when the kernels of ``modules`` are not cached
    yet (the first run after an install pays the compile time once; later runs load it)."""
    if kernels_cached(*modules):
        return
    from rich.console import Console

    Console(stderr=True).print(
        "[dim]compiling numba kernels: the first run after an install takes a few seconds "
        "more; later runs load them from the cache[/dim]"
    )


def laser_input(path: Path | str, data_dir: Path | str | None = None) -> Path:
    """The file a laser-log argument names: the path, or a registered laser dataset's file
    under the data directory (``data_dir``, the ``--data-dir`` option; else
    ``$PROBMAP_DATA``, else ``../shared/data``). A name that is neither is a one-line error
    listing the close registry names."""
    from probmap.datasets.registry import resolve_input

    return resolve_input(path, data_dir, kind="laser")


def print_summary(
    title: str | None,
    rows: Iterable[tuple[str, str]],
    *,
    justify: Literal["left", "right"] = "right",
    console: Console | None = None,
) -> None:
    """Print ``(name, value)`` rows as a borderless two-column table (names in bold).

    Parameters
    ----------
    title : str or None
        Printed above the table.
    rows : iterable of (str, str)
        Already formatted: the library returns numbers, the command chooses their format.
    justify : {"right", "left"}
        Alignment of the value column (right suits numbers).
    console : rich.console.Console, optional
        Where to print (default: a new console on stdout).
    """
    from rich.console import Console
    from rich.table import Table

    table = Table(title=title, show_header=False, box=None)
    table.add_column(style="bold")
    table.add_column(justify=justify)
    for name, value in rows:
        table.add_row(name, value)
    (console or Console()).print(table)


def readings_row(report: Any) -> tuple[str, str]:
    """The one summary row every command that reads laser scans prints: how the readings of
    the log were classified (:class:`probmap.datasets.validate.ReadingReport`)."""
    return ("readings", report.describe())


def pose_source_warning(log: Path | str, pose_source: str, *, chosen: bool = False) -> None:
    """One ``warning:`` line on stderr when a map was built from poses nothing corrected:
    raw odometry (``pose_source == "odometry"``, unless the user ``chosen`` it with
    ``--poses odometry``) or none at all (``"laser"``: a bag read in the laser's frame);
    it names ``probmap slam grid``, which corrects them."""
    name = Path(log).name
    slam = f"'probmap slam grid {name} -o PREFIX'"
    if pose_source == "odometry" and not chosen:
        text = (
            f"the map of {name} is built from raw odometry (its poses are uncorrected), so it "
            f"drifts and smears; {slam} corrects the poses first"
        )
    elif pose_source == "laser":
        text = (
            f"the map of {name} is built from scans without poses (all at the laser's "
            f"origin); {slam} estimates them"
        )
    else:
        return
    typer.echo(f"warning: {text}", err=True)


def input_rows(report: Any, skipped_lines: int = 0) -> list[tuple[str, str]]:
    """:func:`readings_row` (when there is a report) and the skipped bad lines (when any): the
    input part of every laser command's summary."""
    rows = [] if report is None else [readings_row(report)]
    if report is not None:
        skipped_lines = max(skipped_lines, int(report.skipped_lines))
    if skipped_lines:
        rows.append(("skipped bad lines", f"{skipped_lines:,}"))
    return rows


def mapping_rows(result: Any) -> list[tuple[str, str]]:
    """The summary rows of a :class:`~probmap.pipelines.MappingResult` (``probmap map``, local or
    distributed): scans, beams, cells, map size, time, skipped lines, files written."""
    s = result.stats
    spec = result.grid.spec
    rows = [
        ("scans", f"{s.scans:,}"),
        (
            "beams",
            f"{s.beams:,} ({s.hits:,} hits, {s.max_range:,} max-range, {s.dropped:,} dropped)",
        ),
        *input_rows(getattr(result, "readings", None), result.skipped_lines),
        ("cells updated", f"{s.cell_updates:,}"),
        (
            "map size",
            f"{spec.width} x {spec.height} cells at {spec.resolution:g} m "
            f"({spec.width * spec.resolution:.1f} x {spec.height * spec.resolution:.1f} m)",
        ),
        ("observed cells", f"{int(result.grid.observed.sum()):,}"),
        (
            "time",
            f"{result.parse_seconds + result.map_seconds + result.write_seconds:.2f} s "
            f"(parse {result.parse_seconds:.2f}, map {result.map_seconds:.2f}, "
            f"write {result.write_seconds:.2f})",
        ),
    ]
    for f in result.files:
        rows.append(("wrote", str(f)))
    return rows


# Seconds of recent progress the ETA is computed over: long enough that a slow patch (a loop
# closure, a map write) does not make it jump, short enough to follow a real change of pace.
ETA_WINDOW_S = 60.0


def progress_bar(
    description: str = "", *, unit: str = "steps", console: Console | None = None
) -> Any:
    """The progress bar every command shows (on stderr, removed when done).

    Columns: the description, the bar, ``done/total UNIT``, the elapsed time and the time left.
    The time left divides the work still to do by the rate over the last :data:`ETA_WINDOW_S`
    seconds (rich's ``speed_estimate_period``), not by the rate since the start, so it settles
    within a few seconds and then moves smoothly. Use as a context manager::

        with progress_bar("mapping", unit="scans") as bar:
            task = bar.add_task("mapping", total=n)
            ...
            bar.update(task, completed=i)

    Parameters
    ----------
    description : str
        Shown left of the bar (a task's own description is used when this is empty).
    unit : str
        What the counts count (``scans``, ``steps``, ``runs``).
    console : rich.console.Console, optional
        Default: a new console on stderr, so stdout keeps only the summary.
    """
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    console = console or Console(stderr=True)
    if not console.is_terminal:  # a log file, CI, Slurm: lines, not a bar
        return LineProgress(description, unit=unit, file=console.file)
    return Progress(
        TextColumn(description or "{task.description}"),
        BarColumn(),
        TextColumn(f"{{task.completed:,.0f}}/{{task.total:,.0f}} {unit}"),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
        console=console,
        transient=True,
        speed_estimate_period=ETA_WINDOW_S,
    )


def _duration(seconds: float) -> str:
    """``42 s``, ``3 min 07 s``, ``1 h 02 min``.

    >>> _duration(41.6), _duration(187.0), _duration(3720.0)
    ('42 s', '3 min 07 s', '1 h 02 min')
    """
    s = int(round(max(seconds, 0.0)))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


# Seconds a task runs before LineProgress prints its lines (a quick one prints none).
QUIET_S = 2.0


class LineProgress:
    """The progress of :func:`progress_bar` where the output is not a terminal (a log file,
    CI, a Slurm job): one line about every 10 % of each task, with the time so far and the
    time left (the work still to do over the rate of the last :data:`ETA_WINDOW_S` seconds)::

        graph SLAM intel.clf.bz2: 30% (4,090/13,631 scans), 14 s so far, eta 33 s

    The same calls as rich's ``Progress`` that the commands make (``add_task``, ``update``,
    ``advance``, a context manager). Tasks of one step (``total <= 1``) print nothing, nor
    does a task before it has run :data:`QUIET_S` seconds (a quick one prints no line).

    Parameters
    ----------
    description : str
        The lines' prefix (each task's own description when empty).
    unit : str
        What the counts count.
    file : text stream, optional
        Where the lines go (default: ``sys.stderr``).
    clock : callable
        Seconds, monotonic (``time.monotonic``; a test passes its own).
    """

    def __init__(
        self,
        description: str = "",
        *,
        unit: str = "steps",
        file: Any = None,
        clock: Any = None,
    ) -> None:
        import sys
        import time

        self.description = description
        self.unit = unit
        self.file = file if file is not None else sys.stderr
        self.clock = clock or time.monotonic
        self.tasks: dict[int, dict[str, Any]] = {}

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def add_task(self, description: str, total: float | None = 100.0, **_: Any) -> int:
        """A new task; returns its id."""
        now = self.clock()
        tid = len(self.tasks)
        self.tasks[tid] = {
            "description": description, "total": total, "completed": 0.0, "start": now,
            "samples": [(now, 0.0)], "next": 1,
        }  # fmt: skip
        return tid

    def advance(self, task: int, advance: float = 1.0) -> None:
        """Add ``advance`` steps to ``task``."""
        self.update(task, advance=advance)

    def update(
        self,
        task: int,
        *,
        completed: float | None = None,
        total: float | None = None,
        advance: float | None = None,
        description: str | None = None,
        **_: Any,
    ) -> None:
        """Set what ``task`` has done (``completed``, or ``advance`` more), its ``total`` and
        ``description``; print a line when it passed the next tenth of its total."""
        t = self.tasks[task]
        if description is not None:
            t["description"] = description
        if total is not None and total != t["total"]:  # a new phase: its own pace
            t["total"] = total
            t["samples"] = [(self.clock(), t["completed"])]
        if completed is not None:
            t["completed"] = float(completed)
        if advance is not None:
            t["completed"] += float(advance)
        now = self.clock()
        samples = t["samples"]
        samples.append((now, t["completed"]))
        while len(samples) > 2 and now - samples[1][0] >= ETA_WINDOW_S:
            samples.pop(0)  # keep one sample at least the window old
        total_ = t["total"]
        if not total_ or total_ <= 1:
            return
        tenth = int(10 * min(t["completed"] / total_, 1.0) + 1e-9)
        if tenth < t["next"]:
            return
        t["next"] = tenth + 1
        if now - t["start"] >= QUIET_S:  # a task done in a moment says nothing
            self._say(t, now)

    def _say(self, t: dict[str, Any], now: float) -> None:
        done, total = t["completed"], float(t["total"])
        (t0, c0) = t["samples"][0]
        rate = (done - c0) / (now - t0) if now > t0 and done > c0 else 0.0
        left = total - done
        eta = "0 s" if left <= 0 else (_duration(left / rate) if rate > 0 else "unknown")
        name = self.description or t["description"]
        print(
            f"{name}: {100 * done / total:.0f}% ({done:,.0f}/{total:,.0f} {self.unit}), "
            f"{_duration(now - t['start'])} so far, eta {eta}",
            file=self.file,
            flush=True,
        )


_PROCESS_START: list[float] = []


def mark_process_start(t: float) -> None:
    """Record the ``time.perf_counter()`` at which this ``probmap`` process started (the
    console script calls it); the command's first :class:`Stopwatch` then counts the start-up
    before the command ran (imports, argument parsing) as its ``start-up`` phase, so the
    summary's time is the whole wall time the user waited. Commands run in-process (tests,
    ``CliRunner``) never call it and time from their own start."""
    _PROCESS_START[:] = [t]


class Stopwatch:
    """Wall time of a command split into phases (read, compute, write), for its summary.

    >>> import time
    >>> watch = Stopwatch()
    >>> with watch("read"):
    ...     pass
    >>> with watch("compute"):
    ...     pass
    >>> sorted(watch.phases)
    ['compute', 'read']
    >>> watch.row()[0]
    'time'
    """

    def __init__(self) -> None:
        import time

        now = time.perf_counter()
        self.phases: dict[str, float] = {}
        if _PROCESS_START:  # the first stopwatch of a console-script run
            self._start = min(_PROCESS_START.pop(), now)
            self.phases["start-up"] = now - self._start
        else:
            self._start = now

    @contextmanager
    def __call__(self, phase: str) -> Iterator[None]:
        import time

        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.phases[phase] = self.phases.get(phase, 0.0) + time.perf_counter() - t0

    @property
    def total(self) -> float:
        """Seconds since the stopwatch was made (the whole command so far)."""
        import time

        return time.perf_counter() - self._start

    def row(self) -> tuple[str, str]:
        """The summary row: ``("time", "12.3 s (read 1.2 s, compute 10.5 s, write 0.6 s)")``;
        the total covers the whole command, so it is at least the sum of the phases."""
        parts = ", ".join(f"{k} {v:.1f} s" for k, v in self.phases.items())
        return ("time", f"{self.total:.1f} s" + (f" ({parts})" if parts else ""))
