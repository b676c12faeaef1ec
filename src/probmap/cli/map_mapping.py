"""``probmap fit-sensor-model`` and the body of ``probmap map LOG --method map``.

:func:`run_map_method` is what ``probmap map`` calls for ``--method map``: it shows the
objective per sweep while MAP mapping runs and writes the same files as the log-odds method.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from probmap.cli import options as opt
from probmap.cli.common import (
    bad_lines_quiet,
    cli_errors,
    input_rows,
    laser_input,
    print_summary,
)


def run_map_method(
    log: Path,
    output: Path,
    config: Any,
    *,
    p0: float = 0.3,
    max_sweeps: int = 50,
    init: str = "free",
    bag_options: dict[str, Any] | None = None,
) -> Any:
    """MAP mapping of ``log`` with a live display of the objective per sweep; writes
    ``PREFIX.{yaml,pgm,npz,png}`` and prints a summary. ``config`` is a
    :class:`probmap.pipelines.MappingConfig`; ``bag_options`` a bag's topics and frames.
    Returns the written ``MappingResult``.

    Raises the library's errors (call it inside :func:`probmap.cli.common.cli_errors`).
    """
    from probmap.cli.common import Stopwatch, progress_bar
    from probmap.mapping.map_mapping import MapMappingConfig, SweepRecord
    from probmap.pipelines import check_output_prefix, map_log_map, write_map

    watch = Stopwatch()
    log = laser_input(log)
    check_output_prefix(output)
    mcfg = MapMappingConfig(resolution=config.resolution, p0=p0, max_sweeps=max_sweeps, init=init)
    with progress_bar(unit="sweeps") as bar:
        task = bar.add_task(f"MAP {log.name}: indexing beams", total=max_sweeps)

        def tick(rec: SweepRecord) -> None:
            bar.update(
                task,
                completed=rec.sweep,
                description=f"MAP {log.name}: objective {rec.objective:,.1f}, {rec.flips:,} flips",
            )

        result = map_log_map(log, config, tick, map_config=mcfg, bag_options=bag_options)
    from probmap.cli._provenance import command_line

    result = write_map(output, result, config, command=command_line())
    ex = result.extra
    # the pipeline times its own phases; the total is the whole command's
    watch.phases.update(
        read=result.parse_seconds,
        index=float(ex["index_seconds"]),
        sweeps=float(ex["sweep_seconds"]),
        write=result.write_seconds,
    )
    spec = result.grid.spec
    sweeps = int(ex["sweeps"])
    rows = [
        ("scans", f"{result.stats.scans:,}"),
        (
            "beams",
            f"{result.stats.beams:,} ({result.stats.hits:,} windowed, "
            f"{result.stats.max_range:,} max-range, {result.stats.dropped:,} dropped)",
        ),
        *input_rows(result.readings, result.skipped_lines),
        ("beam-cell dependencies", f"{result.stats.cell_updates:,}"),
        ("map size", f"{spec.width} x {spec.height} cells at {spec.resolution:g} m"),
        (
            "objective",
            f"{ex['objective_0']:,.1f} (start) -> {ex['objective']:,.1f} after {sweeps} sweeps"
            + (" (converged)" if ex["converged"] else " (sweep limit reached)"),
        ),
        watch.row(),
    ]
    for f in result.files:
        rows.append(("wrote", str(f)))
    print_summary(f"probmap map --method map {log.name}", rows)
    from probmap.cli.common import pose_source_warning

    pose_source_warning(log, result.pose_source, chosen=config.poses == "odometry")
    return result


@opt.with_option_groups
def fit_sensor_model_command(
    log: Path = typer.Argument(
        ...,
        help="Laser log: CARMEN .clf/.log (plain, .gz, .bz2), ROS 1/2 bag or a dataset name.",
    ),
    output: str | None = opt.output_option(
        "Write the fitted parameters to this YAML file; an existing folder (or a name "
        "ending in /) gets FOLDER/beam_model.yaml. Missing folders are created.",
        default=None,
    ),
    resolution: float | None = opt.resolution_option(
        "Cell size (m) of the map the ranges are cast in [default: 0.05]."
    ),
    every: int | None = typer.Option(None, "--every", help="Use every N-th scan [default: 1]."),
    max_range: float | None = opt.max_range_option(
        "Sensor max range in metres [default: from the log]."
    ),
    poses: str | None = opt.poses_option(
        "corrected: the scans' laser poses; odometry: odometry [default: corrected]."
    ),
    config: Path | None = opt.config_option(
        "A YAML file of FitConfig fields (resolution, every, max_range, poses, "
        "max_iterations, tol); the options given here override it. The output records the "
        "settings used under 'configuration'."
    ),
    skip_bad_lines: bool = opt.skip_bad_lines_option(),
    bag_options: dict[str, Any] = opt.ros_bag_options(),
    data_dir: Path | None = opt.data_dir_option(),
) -> None:
    """Fit the beam model's parameters to a log by EM (Probabilistic Robotics Table 6.2).

    The output YAML holds the parameters under 'beam_model' and what produced them: the
    probmap version, the command line and the settings (a loadable FitConfig) under
    'configuration'."""
    with cli_errors():
        import dataclasses

        import yaml

        from probmap._atomic import atomic_outputs, atomic_write
        from probmap.cli._provenance import command_line
        from probmap.cli.common import Stopwatch, resolve_config
        from probmap.config import dump_config, package_version
        from probmap.pipelines import check_output_prefix
        from probmap.pipelines.fit import FitConfig, fit_scans, read_fit_scans

        watch = Stopwatch()
        log = laser_input(log, data_dir)
        target = None if output is None else check_output_prefix(output, "beam_model.yaml")
        overrides = {"resolution": resolution, "every": every, "max_range": max_range}
        cfg = resolve_config(FitConfig, config, {**overrides, "poses": poses})
        with watch("read"), bad_lines_quiet():
            batch = read_fit_scans(log, cfg, skip_bad_lines=skip_bad_lines, bag_options=bag_options)
        with watch("compute"):
            fit = fit_scans(batch, cfg)
        params = dataclasses.asdict(fit.params)
        rows = [(k, f"{v:.6g}") for k, v in params.items()]
        rows += [
            *input_rows(batch.readings, batch.skipped_lines),
            ("readings fitted", f"{fit.readings:,}"),
            (
                "mean log-likelihood",
                f"{fit.log_likelihood[0]:.4f} -> {fit.log_likelihood[-1]:.4f} in "
                f"{fit.iterations} iterations" + ("" if fit.converged else " (not converged)"),
            ),
        ]
        if target is not None:
            doc = {
                "beam_model": {k: float(v) for k, v in params.items()},
                "probmap_version": package_version(),
                "command": command_line(),
                "configuration": yaml.safe_load(dump_config(cfg)),
            }
            with watch("write"), atomic_outputs(), atomic_write(target, "w") as fh:
                yaml.safe_dump(doc, fh, sort_keys=False)
        rows.append(watch.row())
        if target is not None:
            rows.append(("wrote", str(target)))
        print_summary(f"probmap fit-sensor-model {log.name}", rows)


def register(app: typer.Typer) -> None:
    """Attach ``fit-sensor-model``."""
    app.command("fit-sensor-model", short_help="Fit the beam model's parameters to a log by EM.")(
        fit_sensor_model_command
    )
