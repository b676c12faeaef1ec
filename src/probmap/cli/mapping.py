"""``probmap map`` and ``probmap demo``: occupancy grid mapping with known poses."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import typer

from probmap.cli import options as opt
from probmap.cli._provenance import command_line
from probmap.cli.common import (
    Stopwatch,
    bad_lines_quiet,
    check_choice,
    cli_errors,
    laser_input,
    mapping_rows,
    pose_source_warning,
    print_summary,
    resolve_config,
)
from probmap.cli.watch import live_view_options


def _fmt(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.0f}" if v.is_integer() else f"{v:.4g}"
    return str(v)


@opt.with_option_groups
def map_command(
    logs: list[Path] = typer.Argument(
        ...,
        help="Laser log(s): CARMEN .clf/.log (plain, .gz, .bz2), ROS 1/2 bag or a dataset name "
        "(probmap datasets list). Several logs are mapped together on a Dask cluster.",
    ),
    output: str = opt.output_option(
        "Output prefix: writes PREFIX.{yaml,pgm,npz,png}; an existing folder (or a name "
        "ending in /) writes FOLDER/map.*. Missing folders are created."
    ),
    resolution: float | None = opt.resolution_option(),
    max_range: float | None = opt.max_range_option(
        "Sensor max range in metres (default: from the log)."
    ),
    poses: str | None = opt.poses_option(
        "corrected: the scans' laser poses; odometry: robot odometry + laser offset "
        "[default: corrected]."
    ),
    max_clear: float | None = opt.max_clear_option(
        "Free space cleared by a max-range (no-return) reading, metres [default: 10]."
    ),
    p_hit: float | None = opt.p_hit_option(
        "Inverse model: p(occupied) at a beam's endpoint [default: 0.7]."
    ),
    p_miss: float | None = opt.p_miss_option(
        "Inverse model: p(occupied) along a beam [default: 0.4]."
    ),
    config: Path | None = opt.config_option(
        "A YAML file of MappingConfig fields (as PREFIX.config.yaml records them); the "
        "options given here override it."
    ),
    skip_bad_lines: bool = opt.skip_bad_lines_option(),
    method: str = typer.Option(
        "log-odds",
        "--method",
        help="log-odds: per-cell Bayes filter; map: MAP mapping with the beam model (Table 9.3).",
    ),
    bag_options: dict[str, Any] = opt.ros_bag_options(),
    data_dir: Path | None = opt.data_dir_option(),
    to_bag: Path | None = typer.Option(
        None,
        "--to-bag",
        help="ROS bag: also write the map as nav_msgs/OccupancyGrid into this new bag (.bag: ROS 1, else a ROS 2 folder).",
    ),
    workers: int | None = typer.Option(
        None, "--workers", help="Map on a local Dask cluster with N worker processes."
    ),
    scheduler: str | None = typer.Option(
        None, "--scheduler", help="Map on an existing Dask cluster (scheduler address)."
    ),
    chunks: int = typer.Option(1, "--chunks", help="Dask: split each log into N chunks of scans."),
    allow_partial: bool = typer.Option(
        False, "--allow-partial", help="Dask: write the map of the readable logs when some fail."
    ),
    live: dict[str, Any] = live_view_options(),
) -> None:
    """Build an occupancy grid map from a laser log with known poses."""
    watch = Stopwatch()
    with cli_errors():
        from probmap.pipelines import (
            MappingConfig,
            check_output_folder,
            check_output_prefix,
        )

        # registry names become their files; a missing file is an error (--allow-partial: the
        # run reports it)
        logs = [laser_input(p, data_dir) if p.exists() or not allow_partial else p for p in logs]
        log = logs[0]
        prefix = check_output_prefix(output, "map")
        if to_bag is not None:
            from probmap.datasets.ros.scans import is_bag

            if not is_bag(log):
                raise ValueError(f"--to-bag needs a ROS bag as input; {log} is not one")
            check_output_folder(to_bag.parent if str(to_bag.parent) else Path("."))
            if to_bag.suffix != ".bag" and to_bag.exists():
                raise FileExistsError(f"--to-bag {to_bag}: a ROS 2 bag folder exists already")
        cfg = resolve_config(
            MappingConfig,
            config,
            {
                "resolution": resolution,
                "max_range": max_range,
                "poses": poses,
                "p_hit": p_hit,
                "p_miss": p_miss,
                "max_clear_range": max_clear,
                "skip_bad_lines": True if skip_bad_lines else None,
            },
        )
        local = workers is None and scheduler is None and len(logs) == 1 and chunks == 1
        if (live["viz"] or live["viz_save"] is not None) and not (local and method == "log-odds"):
            raise ValueError(
                "--viz and --viz-save watch the log-odds method on one log (no --method map, "
                "--workers, --scheduler, --chunks or several logs)"
            )
        check_choice("--method", method, ("log-odds", "map"))
        if not local:
            several = len(logs) > 1 or chunks > 1
            cluster: dict[str, Any] = dict(
                workers=workers, scheduler=scheduler, bag_options=bag_options, to_bag=to_bag
            )
            if method == "map" and several:
                raise ValueError(
                    "--method map maps one log as a whole (its sweeps depend on each other): "
                    "not with several logs or --chunks"
                )
            if to_bag is not None and several:
                raise ValueError(
                    "--to-bag writes the map of one bag; not with --chunks or several logs"
                )
            if method == "map":
                from probmap.cli.distributed import run_map_method_distributed

                with _aborted_on_ctrl_c():
                    run_map_method_distributed(log, prefix, cfg, **cluster)
                return
            from probmap.cli.distributed import run_map_distributed

            with _aborted_on_ctrl_c():
                run_map_distributed(
                    logs, prefix, cfg, chunks=chunks, allow_partial=allow_partial, **cluster
                )
            return
        if method == "map":
            from probmap.cli.map_mapping import run_map_method

            with bad_lines_quiet(), _aborted_on_ctrl_c():
                run_map_method(log, prefix, cfg, bag_options=bag_options)
            return
        _map_one(
            log, prefix, cfg, bag_options, to_bag=to_bag, watch=watch, **live
        )  # fmt: skip


@contextmanager
def _aborted_on_ctrl_c() -> Iterator[None]:
    """Ctrl-C in a run that cannot stop part-way (MAP mapping, a cluster): one line, nothing
    written (the outputs are all-or-nothing), exit code 130."""
    try:
        yield
    except KeyboardInterrupt:
        from probmap.cli.common import say_interrupted

        say_interrupted("interrupted: nothing written")
        raise typer.Exit(130) from None


def _map_one(
    log: Path,
    prefix: Path,
    cfg: Any,
    bag_options: dict[str, Any],
    *,
    to_bag: Path | None,
    watch: Stopwatch,
    viz: bool,
    viz_save: Path | None,
    save_partial: bool,
) -> None:
    """``probmap map`` of one log with the log-odds filter: progress bars, the live view,
    Ctrl-C (the map of the scans so far with ``save_partial``), the summary."""

    from probmap._atomic import atomic_outputs
    from probmap.cli.common import progress_bar
    from probmap.cli.watch import (
        interrupted_exit,
        open_view,
        recorded_rows,
        stop_on_ctrl_c,
        view_discarded_on_error,
    )
    from probmap.pipelines import map_log, write_map

    view = open_view(f"probmap map {log.name}", viz, viz_save)
    observer = None
    if view is not None:
        from probmap.viz.live import MappingObserver

        observer = MappingObserver(view)
    with view_discarded_on_error(view):
        with (
            progress_bar(unit="scans") as bar,
            bad_lines_quiet(),
            stop_on_ctrl_c(save_partial, "chunk of scans") as stop,
        ):
            task = bar.add_task(f"reading {log.name}", total=1)

            def tick(done: int, total: int) -> None:
                bar.update(task, description=f"mapping {log.name}", completed=done, total=total)

            setup = watch.total  # imports, checks, the viewer
            result = map_log(
                log, cfg, progress=tick, bag_options=bag_options, observer=observer, stop=stop
            )
        watch.phases.update(setup=setup, read=result.parse_seconds, compute=result.map_seconds)
        asked = stop is not None and stop()  # a Ctrl-C during the last chunk ends no earlier
        if result.interrupted and result.stats.scans == 0:  # no map to write (the view goes)
            interrupted_exit(0, result.scans_total, "scans", wrote=False)
        if observer is not None:
            observer.finish(result)
        with watch("write"), progress_bar(unit="maps") as bar:
            bar.add_task(f"writing {prefix.name}.*", total=1)
            with atomic_outputs() as outputs:  # the map files and the bag: all or none
                result = write_map(prefix, result, cfg, command=command_line())
                files = [str(f) for f in result.files]
                if to_bag is not None:
                    from probmap.datasets.ros.maps import write_map_to_bag
                    from probmap.datasets.ros.scans import RosBag

                    frame = RosBag(log, **bag_options).resolve_frames()[0]
                    outputs.folder(to_bag.parent if str(to_bag.parent) else Path("."))
                    files.append(str(write_map_to_bag(to_bag, result.grid, frame_id=frame)))
    if view is not None:
        view.close()
    rows = [r for r in mapping_rows(result) if r[0] not in ("time", "wrote")]
    rows += [watch.row(), *(("wrote", f) for f in files), *recorded_rows(viz_save)]
    if result.interrupted or asked:
        rows.insert(0, ("interrupted", f"at scan {result.stats.scans:,} of {result.scans_total:,}"))
    print_summary(f"probmap map {log.name}", rows)
    pose_source_warning(log, result.pose_source, chosen=cfg.poses == "odometry")
    if result.interrupted or asked:
        interrupted_exit(result.stats.scans, result.scans_total, "scans", wrote=True)


def demo_command(
    output: Path = opt.output_option(
        "Output folder (created when missing): map.*, or trajectory.csv (--localize), or "
        "semantic.* and semantic.occupancy.* (--semantic).",
        default=Path("probmap-demo"),
    ),
    seed: int = typer.Option(0, "--seed", help="Seed of the simulated world."),
    localize: bool = typer.Option(
        False, "--localize", help="Run Monte Carlo localization on the simulated world instead."
    ),
    semantic: bool = typer.Option(
        False, "--semantic", help="Map a labelled simulated world into a semantic grid instead."
    ),
    config: Path | None = opt.config_option(
        "A YAML file of MappingConfig fields (resolution, inverse sensor model, prior, "
        "clamp) for the mapping demo; recorded as map.config.yaml."
    ),
) -> None:
    """Map a simulated floor plan (no download) and report its accuracy against the truth."""
    watch = Stopwatch()
    with cli_errors():
        from probmap.pipelines import check_output_folder

        if localize and semantic:
            raise ValueError("choose one of --localize and --semantic")
        if config is not None and (localize or semantic):
            raise ValueError("--config sets the mapping demo (not --localize or --semantic)")
        check_output_folder(output)
        if semantic:
            from probmap.cli.semantic import print_semantic_demo
            from probmap.pipelines.semantic import run_semantic_demo

            print_semantic_demo(run_semantic_demo(output))
            return
        if localize:
            from probmap.pipelines.demo import run_localize_demo

            summary = run_localize_demo(output)
            print_summary("probmap demo --localize", [(k, _fmt(v)) for k, v in summary.items()])
            return
        from probmap.cli.common import note_first_compile, progress_bar
        from probmap.pipelines import MappingConfig, check_output_prefix, run_mapping_demo

        prefix = check_output_prefix(output / "map")
        cfg = None if config is None else resolve_config(MappingConfig, config)
        note_first_compile("probmap.grid._kernels")
        with progress_bar(unit="runs") as bar:
            bar.add_task("simulating, mapping and writing the demo", total=1)
            setup = watch.total  # imports, checks
            demo = run_mapping_demo(prefix, seed=seed, config=cfg, command=command_line())
        m = demo.mapping
        # the pipeline times its phases; the stopwatch's total covers the whole command
        watch.phases.update(
            setup=setup, simulate=m.parse_seconds, compute=m.map_seconds, write=m.write_seconds
        )
        rows = [r for r in mapping_rows(m) if r[0] not in ("time", "wrote")]
        rows.insert(
            0,
            (
                "accuracy",
                f"{100 * demo.accuracy:.2f} % of {demo.cells_classified:,} observed cells "
                "classified correctly against the ground truth",
            ),
        )
        rows += [watch.row(), *(("wrote", str(f)) for f in m.files)]
        print_summary("probmap demo: simulated floor plan", rows)


def register(app: typer.Typer) -> None:
    """Attach the mapping commands."""
    app.command("map", short_help="Occupancy grid map from a laser log with known poses.")(
        map_command
    )
    app.command("demo", short_help="Map a simulated floor plan and score it (no download).")(
        demo_command
    )
