"""``probmap map LOG... --workers N | --scheduler ADDRESS``: mapping a fleet's logs on Dask.

``probmap map`` (in :mod:`probmap.cli.mapping`) delegates here when it is given several logs,
``--workers`` or ``--scheduler``. This module only parses, delegates to
:func:`probmap.pipelines.distributed.map_logs_distributed`, and prints.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from probmap.cli._provenance import command_line

if TYPE_CHECKING:
    from probmap.pipelines import MappingConfig
    from probmap.pipelines.distributed import DistributedMappingResult


def _inputs_table(result: DistributedMappingResult) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title="inputs")
    table.add_column("log")
    table.add_column("status")
    for p in result.mapped:
        table.add_row(str(p), "[green]mapped[/green]")
    for p, msg in result.failed:
        table.add_row(str(p), f"[red]failed:[/red] {msg}")
    Console(stderr=bool(result.failed)).print(table)


def write_bag(
    outputs: Any, to_bag: Path, source: Path, mapping: Any, bag_options: dict[str, Any] | None
) -> Path:
    """Write ``mapping.grid`` into the new bag ``to_bag`` in the frame of the bag ``source``
    (inside the caller's :func:`probmap._atomic.atomic_outputs` block ``outputs``)."""
    from probmap.datasets.ros.maps import write_map_to_bag
    from probmap.datasets.ros.scans import RosBag

    frame = RosBag(source, **(bag_options or {})).resolve_frames()[0]
    outputs.folder(to_bag.parent if str(to_bag.parent) else Path("."))
    return Path(write_map_to_bag(to_bag, mapping.grid, frame_id=frame))


def _one_cluster(workers: int | None, scheduler: str | None) -> None:
    """Refuse ``--workers`` (a local cluster) together with ``--scheduler`` (a running one)."""
    from probmap.cli.common import CliError

    if workers is not None and scheduler is not None:
        raise CliError("give either --workers (a local cluster) or --scheduler, not both")


def run_map_method_distributed(
    log: Path,
    output: Path,
    config: MappingConfig,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    bag_options: dict[str, Any] | None = None,
    to_bag: Path | None = None,
) -> Any:
    """``probmap map --method map`` with ``--workers`` or ``--scheduler``: MAP mapping of one log
    as one task on the cluster; writes the map files (and ``to_bag``) and prints a summary."""
    from probmap._atomic import atomic_outputs
    from probmap.cli.common import CliError, mapping_rows, print_summary
    from probmap.pipelines import check_output_prefix, write_map
    from probmap.pipelines.distributed import DistributedMappingError, map_log_map_distributed

    _one_cluster(workers, scheduler)
    check_output_prefix(output)
    try:
        result = map_log_map_distributed(
            log, config, workers=workers, scheduler=scheduler, bag_options=bag_options
        )
    except DistributedMappingError as exc:
        raise CliError(str(exc)) from None
    with atomic_outputs() as outputs:  # the map files and the bag: all or none
        mapping = write_map(output, result, config, command=command_line())
        rows = mapping_rows(mapping)
        if to_bag is not None:
            rows.append(("wrote", str(write_bag(outputs, to_bag, log, mapping, bag_options))))
    rows.append(("mode", "MAP mapping, one task on the cluster"))
    print_summary("probmap map --method map (distributed)", rows)
    return mapping


def run_map_distributed(
    logs: Sequence[Path],
    output: Path,
    config: MappingConfig,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    chunks: int = 1,
    allow_partial: bool = False,
    bag_options: dict[str, Any] | None = None,
    to_bag: Path | None = None,
) -> DistributedMappingResult:
    """Map ``logs`` on a local (``workers``) or existing (``scheduler``) Dask cluster and write
    ``PREFIX.{yaml,pgm,npz,png}``; prints Dask's progress, the inputs and a summary.

    Exits with status 1 (writing nothing) when an input fails, unless ``allow_partial``: then the
    map of the other inputs is written, the failures listed, and the exit status is still 1.
    ``to_bag`` (one bag as input) also writes the map into that new bag, with the map files.
    """
    from probmap._atomic import atomic_outputs
    from probmap.cli.common import CliError, mapping_rows, print_summary
    from probmap.pipelines import check_output_prefix, write_map
    from probmap.pipelines.distributed import (
        DistributedMappingError,
        DistributedOptions,
        map_logs_distributed,
    )

    _one_cluster(workers, scheduler)
    check_output_prefix(output)
    try:
        result = map_logs_distributed(
            logs,
            config,
            workers=workers,
            scheduler=scheduler,
            progress=True,
            options=DistributedOptions(chunks=chunks),
            allow_partial=allow_partial,
            bag_options=bag_options,
        )
    except ImportError as exc:
        raise CliError(str(exc)) from None
    except DistributedMappingError as exc:
        if exc.result is not None:
            _inputs_table(exc.result)
        raise CliError(f"{exc} (no map written; --allow-partial writes the others)") from None
    with atomic_outputs() as outputs:  # the map files and the bag: all or none
        mapping = write_map(output, result.as_mapping_result(), config, command=command_line())
        rows = mapping_rows(mapping)
        if to_bag is not None:
            rows.append(("wrote", str(write_bag(outputs, to_bag, logs[0], mapping, bag_options))))
    _inputs_table(result)
    rows.append(("mode", f"{result.mode} ({result.tasks} tasks on {result.workers} workers)"))
    print_summary("probmap map (distributed)", rows)
    if result.failed:
        raise typer.Exit(1)
    return result
