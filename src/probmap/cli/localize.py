"""``probmap localize``: Monte Carlo localization of a laser log on a map_server map."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from probmap._atomic import atomic_path
from probmap.cli.common import (
    CliError,
    bag_options_of,
    cli_errors,
    fixed_frame_option,
    input_rows,
    laser_frame_option,
    laser_input,
    odom_topic_option,
    print_summary,
    scan_topic_option,
    skip_bad_lines_option,
)


def _plot(ax: Any, spec: Any, probability: Any, poses: Any, reference: Any | None) -> None:
    """Draw the map (grey, unknown light blue) and the trajectories on ``ax``."""
    import numpy as np

    p = np.asarray(probability, dtype=float)
    img = np.where(np.isnan(p), 0.75, 1.0 - p)
    x0, y0 = spec.origin
    h, w = p.shape
    r = spec.resolution
    ax.imshow(
        img, cmap="gray", origin="lower", extent=(x0, x0 + w * r, y0, y0 + h * r), vmin=0, vmax=1
    )
    if reference is not None and len(reference):
        ax.plot(reference[:, 0], reference[:, 1], "-", color="tab:green", lw=0.8, label="reference")
    ax.plot(poses[:, 0], poses[:, 1], "-", color="tab:red", lw=0.8, label="MCL")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal")
    ax.legend(loc="upper right")


def _read_reference(
    path: Path,
    offset: float,
    skip_bad_lines: bool = False,
    bag_options: dict[str, Any] | None = None,
) -> tuple[Any, Any]:
    """Reference (times (M,), poses (M, 3)) from a CSV (time,x,y,theta), or the laser poses
    of a laser log (CARMEN, ROS 1/2 bag, registry name; ``bag_options`` apply to a bag)."""
    import numpy as np

    if path.suffix.lower() != ".csv" or not path.exists():
        path = laser_input(path)
    if path.suffix.lower() == ".csv":
        try:
            data = np.loadtxt(path, delimiter=",", skiprows=1, usecols=(0, 1, 2, 3), ndmin=2)
        except ValueError as exc:
            raise CliError(f"{path}: expected CSV columns time,x,y,theta: {exc}") from None
        return data[:, 0] + offset, data[:, 1:4]
    from probmap.datasets.rosbag import is_bag
    from probmap.datasets.scans import open_scans

    ref = open_scans(
        path,
        skip_bad_lines=skip_bad_lines,
        bag_options=bag_options if is_bag(path) else None,
        require_readings=False,  # only its poses are used
    )
    return ref.times + offset, ref.laser_poses


def localize_command(
    map_yaml: Path = typer.Argument(..., help="map_server YAML map (e.g. from probmap map)."),
    log: Path = typer.Argument(
        ...,
        help="Laser log with odometry: CARMEN (plain, .gz, .bz2), ROS 1/2 bag or a dataset name.",
    ),
    output: Path = typer.Option(
        ...,
        "-o",
        "--output",
        help="Output folder (created when missing): trajectory.csv and trajectory.png.",
    ),
    particles: int | None = typer.Option(
        None, "--particles", "-n", help="Number of particles [default: 2000]."
    ),
    global_: bool = typer.Option(
        False, "--global", help="Global localization: start from particles over free space."
    ),
    reference: Path | None = typer.Option(
        None,
        "--reference",
        help="Reference trajectory: CSV time,x,y,theta, or the laser poses of a CARMEN log, "
        "ROS bag or dataset name.",
    ),
    reference_offset: float = typer.Option(
        0.0,
        "--reference-offset",
        help="Seconds added to the reference times (Intel corrected log: 976052857.337284).",
    ),
    tum: bool = typer.Option(
        False,
        "--tum",
        help="Also write trajectory.tum: the trajectory in the TUM format (evo_ape, evo_rpe).",
    ),
    seed: int | None = typer.Option(None, "--seed", help="Random seed [default: 0]."),
    config: Path | None = typer.Option(
        None,
        "--config",
        help="A YAML file of LocalizeConfig fields (as OUTPUT/config.yaml records them); the "
        "options given here override it.",
    ),
    allow_lost: bool = typer.Option(
        False,
        "--allow-lost",
        help="Write the trajectory even when the filter loses track (its particles spread "
        "beyond 3 m, or its estimate leaves the map's free space, for 10 updates); without it "
        "that is an error and nothing is written.",
    ),
    start: int = typer.Option(0, "--start", help="First scan to use."),
    stop: int | None = typer.Option(None, "--stop", help="Scan to stop before."),
    skip_bad_lines: bool = skip_bad_lines_option(),
    scan_topic: str | None = scan_topic_option(),
    odom_topic: str | None = odom_topic_option(),
    fixed_frame: str | None = fixed_frame_option(),
    laser_frame: str | None = laser_frame_option(),
) -> None:
    """Track (or globally localize) the robot of a laser log on a map with MCL: writes
    trajectory.csv, trajectory.png and config.yaml (the settings used, with the probmap
    version; and trajectory.tum with --tum) into OUTPUT."""
    with cli_errors():
        import warnings

        import numpy as np
        from rich.console import Console
        from rich.progress import Progress
        from rich.table import Table

        from probmap._atomic import atomic_outputs
        from probmap.datasets.scans import open_scans
        from probmap.grid.io import read_map_server
        from probmap.pipelines import check_output_folder
        from probmap.pipelines.localize import (
            FilterLostWarning,
            LocalizeConfig,
            localize_scans,
            match_times,
            trajectory_errors,
        )

        if particles is not None and particles <= 0:
            raise CliError(f"--particles must be positive, got {particles}")
        from probmap.cli.common import resolve_config

        overrides = {
            "n_particles": particles,
            "global_localization": True if global_ else None,
            "seed": seed,
        }
        cfg = resolve_config(LocalizeConfig, config, overrides)
        if not map_yaml.exists():
            raise FileNotFoundError(f"{map_yaml}: no such file")
        log = laser_input(log)
        check_output_folder(output)

        from probmap.errors import BadLinesWarning

        bags = bag_options_of(scan_topic, odom_topic, fixed_frame, laser_frame)
        m = read_map_server(map_yaml)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", BadLinesWarning)  # counted in the summary
            batch = open_scans(
                log, poses="odometry", skip_bad_lines=skip_bad_lines, bag_options=bags
            )
        odo = np.asarray(batch.robot_poses)
        if odo.shape[0] < 2 or np.all(odo == odo[0]):
            raise CliError(f"{log}: no odometry (every scan carries the same robot pose)")
        angles = np.asarray(batch.angles)
        if angles.ndim != 1:
            raise CliError(f"{log}: scans with differing beam geometry are not supported")
        ref_t = ref_p = None
        always = None
        if reference is not None:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", BadLinesWarning)
                ref_t, ref_p = _read_reference(reference, reference_offset, skip_bad_lines, bags)
            always, _ = match_times(batch.times, ref_t)
            if always.size == 0:
                raise CliError(
                    f"{reference}: no reference time within 20 ms of a scan "
                    "(check --reference-offset)"
                )
        with Progress(transient=True) as bar:
            task = bar.add_task(f"localizing {log.name}", total=None)

            def tick(done: int, total: int) -> None:
                bar.update(task, completed=done, total=total)

            with warnings.catch_warnings():  # a lost filter is reported below, in one line
                warnings.simplefilter("ignore", FilterLostWarning)
                run = localize_scans(
                    m.spec,
                    m.probability,
                    batch.times,
                    batch.ranges,
                    angles,
                    odo,
                    batch.max_range,
                    cfg,
                    start=start,
                    stop=stop,
                    always_update=always,
                    progress=tick,
                )
        if run.lost is not None and not allow_lost:
            raise CliError(
                f"{log}: {run.lost.describe()}; nothing written (--allow-lost writes the "
                "trajectory anyway)"
            )
        errors = None
        if ref_t is not None and ref_p is not None:
            errors = trajectory_errors(run, ref_t, ref_p)
            if errors[0].size == 0:
                raise CliError("no update coincides with a reference pose")
        rows = np.column_stack([run.times, run.poses, run.spread])
        traj = output / "trajectory.csv"
        plot = output / "trajectory.png"
        from matplotlib.figure import Figure

        fig = Figure(figsize=(8, 8))
        _plot(fig.add_subplot(), m.spec, m.probability, run.poses, ref_p)
        extra: list[Path] = []
        with atomic_outputs():  # every file or none; a missing folder is created
            with atomic_path(traj) as tmp:
                np.savetxt(
                    tmp, rows, delimiter=",", fmt="%.6f", header="time,x,y,theta,spread",
                    comments="",
                )  # fmt: skip
            with atomic_path(plot) as tmp:
                fig.savefig(tmp, dpi=120, format="png")
            if tum:
                from probmap.datasets.tum import write_tum

                extra.append(write_tum(output / "trajectory.tum", run.times, run.poses))
            from probmap.config import write_config

            extra.append(write_config(output / "config.yaml", cfg))

        console = Console()
        summary_rows = [
            *input_rows(batch.readings, batch.skipped_lines),
            ("updates", f"{run.times.size:,}"),
            ("final spread", f"{run.spread[-1]:.3f} m" if run.spread.size else "-"),
            *([("lost", run.lost.describe())] if run.lost is not None else []),
            ("wrote", ", ".join(str(f) for f in (traj, plot, *extra))),
        ]
        print_summary(f"probmap localize {log.name}", summary_rows, console=console)
        if errors is not None:
            err, head = errors
            table = Table(title=f"error against {reference.name if reference else ''}")
            for col in ("", "n", "median", "mean", "95th pct", "max"):
                table.add_column(col, justify="right")
            for name, e, unit in (("position", err, "m"), ("heading", np.degrees(head), "deg")):
                table.add_row(
                    name,
                    f"{e.size}",
                    f"{np.median(e):.3f} {unit}",
                    f"{e.mean():.3f} {unit}",
                    f"{np.percentile(e, 95):.3f} {unit}",
                    f"{e.max():.3f} {unit}",
                )
            console.print(table)


def register(app: typer.Typer) -> None:
    """Attach ``probmap localize``."""
    app.command("localize")(localize_command)
