"""``probmap localize``: Monte Carlo localization of a laser log on a map_server map or in a
graph-SLAM session."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from probmap._atomic import atomic_path
from probmap.cli import options as opt
from probmap.cli.common import (
    CliError,
    Stopwatch,
    bad_lines_quiet,
    cli_errors,
    input_rows,
    laser_input,
    print_summary,
)
from probmap.cli.watch import recorded_rows, viz_option, viz_save_option


def _found_offset(batch: Any, ref_t: Any, ref_p: Any) -> tuple[Any, tuple[str, str]]:
    """The reference's times on the log's clock (:func:`probmap.geometry.timesync.
    find_time_offset` of the log's odometry and the reference), and the summary row that
    states the offset found; one ``note:`` line on stderr says it at once."""
    from probmap.geometry.timesync import find_time_offset

    found = find_time_offset(batch.times, batch.robot_poses, ref_t, ref_p)
    typer.echo(
        f"note: reference time offset {found.offset:+.6f} s, found by lining up the motion "
        f"(correlation {found.correlation:.2f}, {100 * found.matched:.0f}% of its stamps on a "
        "scan's); --reference-offset overrides it",
        err=True,
    )
    text = f"{found.offset:+.6f} s (found)"
    return ref_t + found.offset, ("reference offset", text)


def _read_reference(
    path: Path,
    offset: float,
    skip_bad_lines: bool = False,
    bag_options: dict[str, Any] | None = None,
    data_dir: Path | None = None,
) -> tuple[Any, Any]:
    """Reference (times (M,), poses (M, 3)) from a CSV (time,x,y,theta), or the laser poses
    of a laser log (CARMEN, ROS 1/2 bag, registry name; ``bag_options`` apply to a bag)."""
    import numpy as np

    if path.suffix.lower() != ".csv" or not path.exists():
        path = laser_input(path, data_dir)
    if path.suffix.lower() == ".csv":
        try:
            data = np.loadtxt(path, delimiter=",", skiprows=1, usecols=(0, 1, 2, 3), ndmin=2)
        except ValueError as exc:
            raise CliError(f"{path}: expected CSV columns time,x,y,theta: {exc}") from None
        return data[:, 0] + offset, data[:, 1:4]
    from probmap.datasets.ros.scans import is_bag
    from probmap.datasets.scans import open_scans

    ref = open_scans(
        path,
        skip_bad_lines=skip_bad_lines,
        bag_options=bag_options if is_bag(path) else None,
        require_readings=False,  # only its poses are used
    )
    return ref.times + offset, ref.laser_poses


def _laser_offset(
    log: Path, batch: Any, m: Any, skip_bad_lines: bool, bags: dict[str, Any] | None
) -> Any:
    """The laser's mounting pose in the robot frame (3,): a session's own where the log is the
    session's (its map and poses were built with it), else ``between(robot, laser)`` of the
    log's poses, else (a corrected log, whose laser poses are not the odometry's) the one its
    odometry reading composes (CARMEN: PARAM ``robot_frontlaser_offset``)."""
    import numpy as np

    from probmap.datasets.scans import open_scans
    from probmap.pipelines.localize import laser_offset_of, match_times

    robot = np.asarray(batch.robot_poses)
    if m.times is not None and m.odometry is not None:
        i, j = match_times(batch.times, m.times)
        if i.size:
            mount = laser_offset_of(robot[i], m.odometry[j])
            if mount is not None:
                return mount
    mount = laser_offset_of(robot, np.asarray(batch.laser_poses))
    if mount is None:
        odo = open_scans(
            log, poses="odometry", skip_bad_lines=skip_bad_lines, bag_options=bags,
            require_readings=False,
        )  # fmt: skip
        mount = laser_offset_of(odo.robot_poses, odo.laser_poses)
    return np.zeros(3) if mount is None else mount


def _describe_offset(mount: Any) -> str:
    """``x, y m, theta deg`` of the laser in the robot frame."""
    import math

    x, y, th = (float(v) for v in mount)
    return f"{x:.3f}, {y:.3f} m, {math.degrees(th):.1f} deg (laser in the robot frame)"


def _convergence_rows(run: Any, global_: bool) -> list[tuple[str, str]]:
    """Where a global localization converged (or that it did not), and the hypotheses the
    particles hold at the end: one place, or several with their weights and spreads."""
    import numpy as np

    rows = []
    if global_:
        c = run.converged_index
        if c is None:
            rows.append(
                ("converged", "no: the particles never formed one tight cluster whose scans fit "
                 "the map (or it stopped fitting)")
            )  # fmt: skip
        elif not run.localized:
            rows.append(
                ("converged", "no: at the end its particles hold several places, or the scans "
                 "do not fit the map there")
            )  # fmt: skip
        if not run.localized and run.matched.size:
            fit, through = (float(np.mean(v[-10:])) for v in (run.matched, run.see_through))
            rows.append(
                ("scan fit", f"{fit:.0%} of the beams near an obstacle, {through:.0%} through "
                 "a wall (last 10 updates)")
            )  # fmt: skip
        else:
            k, t = int(run.scan_index[c]), float(run.times[c])
            rows.append(("converged", f"at update {c + 1:,} (scan {k}, t = {t:.2f} s)"))
        if run.restarts:
            rows.append(
                ("search", f"started again {run.restarts} time(s): its particles had settled "
                 "where the scans do not fit the map")
            )  # fmt: skip
    hyps = run.hypotheses
    if len(hyps) == 1:
        h = hyps[0]
        rows.append(("hypotheses", f"1 (weight {h.weight:.2f}, spread {h.spread:.2f} m)"))
    elif hyps:
        each = "; ".join(
            f"{h.weight:.2f} at ({h.mean[0]:.1f}, {h.mean[1]:.1f}) m, spread {h.spread:.2f} m"
            for h in hyps[:5]
        )
        rows.append(("hypotheses", f"{len(hyps)}, not one place: {each}"))
    return rows


def _particle_rows(run: Any, cfg: Any) -> list[tuple[str, str]]:
    """How many particles the filter used: the count at the start and at the end, and the
    most, with KLD-sampling; the fixed count without it."""
    n = run.particle_count
    if not n.size:
        return []
    if not cfg.kld or n.min() == n.max():
        return [("particles", f"{int(n[0]):,}")]
    return [
        ("particles", f"{int(n[0]):,} after the first update, {int(n[-1]):,} at the end, "
         f"{int(n.min()):,}-{int(n.max()):,} (KLD-sampling)")
    ]  # fmt: skip


@opt.with_option_groups
def localize_command(
    first: Path = typer.Argument(
        ...,
        metavar="MAP",
        help="The map: a map_server YAML map (e.g. from probmap map) or a session saved by "
        "probmap slam grid --save-session. With --map, this is the LOG.",
    ),
    second: Path | None = typer.Argument(
        None,
        metavar="LOG",
        help="Laser log with odometry: CARMEN (plain, .gz, .bz2), ROS 1/2 bag or a dataset name.",
    ),
    map_option: Path | None = typer.Option(
        None,
        "--map",
        help="The map as an option (then the one argument is the log): a map_server YAML map or "
        "a graph-SLAM session (data: reading one runs no code; a folder: its slam.session). A "
        "session's map "
        "is its occupancy grid at its optimized poses, and its trajectory is the reference when "
        "--reference is not given.",
    ),
    output: Path = opt.output_option(
        "Output folder (created when missing): trajectory.csv (the robot's poses) and "
        "trajectory.png."
    ),
    particles: int | None = opt.particles_option(
        "Particles while tracking, the fewest KLD-sampling keeps [default: 2000]. A global "
        "localization starts with more: 30 per m2 of free space (particle_density)."
    ),
    global_: bool = typer.Option(
        False, "--global", help="Global localization: start from particles over free space."
    ),
    reference: Path | None = typer.Option(
        None,
        "--reference",
        help="Reference trajectory of the laser, compared with the robot's poses composed with "
        "the laser mounting (from the log's robot and laser poses): CSV time,x,y,theta (as "
        "slam grid's trajectory.csv), or the laser poses of a CARMEN log, ROS bag or dataset "
        "name.",
    ),
    reference_offset: float | None = typer.Option(
        None,
        "--reference-offset",
        help="Seconds added to the reference times [default: found by lining up the "
        "reference's motion with the log's odometry, and printed].",
    ),
    tum: bool = opt.tum_option(),
    seed: int | None = opt.seed_option(),
    config: Path | None = opt.config_option(
        "A YAML file of LocalizeConfig fields (as OUTPUT/config.yaml records them); the "
        "options given here override it."
    ),
    allow_lost: bool = typer.Option(
        False,
        "--allow-lost",
        help="Write the trajectory even when the filter ends lost (its particles spread "
        "beyond 3 m, or its estimate left the map's free space, for 10 updates, and it did not "
        "recover); without it that is an error and nothing is written. The summary names "
        "every time it lost track and when it recovered.",
    ),
    start: int = typer.Option(0, "--start", help="First scan to use."),
    stop: int | None = typer.Option(None, "--stop", help="Scan to stop before."),
    skip_bad_lines: bool = opt.skip_bad_lines_option(),
    bag_options: dict[str, Any] = opt.ros_bag_options(),
    data_dir: Path | None = opt.data_dir_option(),
    viz: bool = viz_option(),
    viz_save: Path | None = viz_save_option(
        "Record the live view (map, particles, estimate and trajectory, scan, reference) "
        "into FILE.rrd, to open later with 'rerun FILE.rrd' (extra 'viz')."
    ),
) -> None:
    """Track (or globally localize) the robot of a laser log on a map with MCL: writes
    trajectory.csv, trajectory.png (the map, the final particles, the trajectory from the
    filter's convergence on and the reference over the localized span) and config.yaml (the
    settings used, with the command line and the probmap version; and trajectory.tum with
    --tum) into OUTPUT. The map is a map_server map or a session of probmap slam grid."""
    watch = Stopwatch()  # the whole command: its summary's time row
    with cli_errors():
        import dataclasses
        import warnings

        import numpy as np
        from rich.console import Console
        from rich.table import Table

        from probmap._atomic import atomic_outputs
        from probmap.cli._provenance import write_run_config
        from probmap.cli.common import progress_bar, resolve_config
        from probmap.datasets.scans import open_scans
        from probmap.pipelines import check_output_folder
        from probmap.pipelines.localize import (
            FilterLostWarning,
            LocalizeConfig,
            load_localization_map,
            localize_scans,
            match_times,
            trajectory_errors,
        )

        if map_option is not None:
            if second is not None:
                raise CliError("--map names the map: give the log as the only argument")
            map_path, log = map_option, first
        elif second is None:
            raise CliError("missing the LOG argument (probmap localize MAP LOG, or LOG --map MAP)")
        else:
            map_path, log = first, second
        if particles is not None and particles <= 0:
            raise CliError(f"--particles must be positive, got {particles}")
        overrides = {
            "n_particles": particles,
            "global_localization": True if global_ else None,
            "seed": seed,
        }
        cfg = resolve_config(LocalizeConfig, config, overrides)
        if viz_save is not None and viz_save.suffix != ".rrd":
            raise CliError(f"--viz-save {viz_save}: a recording is saved as FILE.rrd")
        log = laser_input(log, data_dir)
        check_output_folder(output)
        if viz_save is not None:
            check_output_folder(viz_save.parent if str(viz_save.parent) else Path("."))

        with watch("read"):
            m = load_localization_map(map_path)
            with bad_lines_quiet():
                # the log's own laser poses: beside the robot's they give the mounting
                batch = open_scans(
                    log, poses="corrected", skip_bad_lines=skip_bad_lines, bag_options=bag_options
                )
            odo = np.asarray(batch.robot_poses)
            if odo.shape[0] < 2 or np.all(odo == odo[0]):
                raise CliError(f"{log}: no odometry (every scan carries the same robot pose)")
            angles = np.asarray(batch.angles)  # (B,), or (S, B) when beam counts differ
            if not 0 <= start < len(batch.times):
                raise CliError(f"--start {start}: the log has {len(batch.times):,} scans")
            mount = _laser_offset(log, batch, m, skip_bad_lines, bag_options)
            ref_t = ref_p = None
            ref_name = None
            offset_row: tuple[str, str] | None = None
            if reference is not None:
                with bad_lines_quiet():
                    ref_t, ref_p = _read_reference(
                        reference, reference_offset or 0.0, skip_bad_lines, bag_options, data_dir
                    )
                if reference_offset is None:  # the two logs' clocks, lined up by their motion
                    ref_t, offset_row = _found_offset(batch, ref_t, ref_p)
                # the reference is compared at its own times, interpolated between the
                # filter's updates: it never makes the filter update (trajectory_errors)
                if match_times(batch.times, ref_t)[0].size == 0:
                    raise CliError(
                        f"{reference}: no reference time within 20 ms of a scan "
                        "(check --reference-offset)"
                    )
                ref_name = reference.name
            elif m.times is not None and m.poses is not None:
                # a session: its own trajectory, where the log's scans are the session's
                if match_times(batch.times, m.times)[0].size:
                    ref_t, ref_p = m.times, m.poses
                    ref_name = f"the session's trajectory ({map_path.name})"
            if m.kind == "session" and not cfg.global_localization and cfg.initial_pose is None:
                # the session knows where the robot was at the log's first scan (the log being
                # the session's own, or a part of it); otherwise the odometry frame is taken
                # for the map frame, as with a map file
                pose0 = m.pose_at(float(batch.times[start]))
                if pose0 is not None:  # the session's pose is the laser's: the robot's is behind
                    from probmap.geometry.se2 import compose, inverse

                    robot0 = compose(pose0, inverse(mount))
                    cfg = dataclasses.replace(cfg, initial_pose=tuple(float(v) for v in robot0))

        observer = None
        if viz or viz_save is not None:
            from probmap.viz.live import LiveView, LocalizationObserver

            # rerun's application ids take no dots: "intel.clf.bz2" would be renamed with a
            # warning on the terminal
            app_id = "probmap localize " + log.name.replace(".", "-")
            view = LiveView(app_id, save=viz_save, spawn=viz)
            span = None
            if ref_t is not None and ref_p is not None:
                last = len(batch.times) if stop is None else min(stop, len(batch.times))
                t0, t1 = batch.times[start], batch.times[last - 1]
                span = ref_p[(ref_t >= t0) & (ref_t <= t1)]
            observer = LocalizationObserver(view, m, batch.max_range, reference=span)
        stop_at = len(batch.times) if stop is None else min(stop, len(batch.times))
        with watch("compute"), progress_bar(f"localizing {log.name}", unit="scans") as bar:
            task = bar.add_task("localizing", total=max(stop_at - start, 0))

            def tick(done: int, total: int) -> None:
                bar.update(task, completed=done, total=total)

            try:
                with warnings.catch_warnings():  # a lost filter is reported below, in one line
                    warnings.simplefilter("ignore", FilterLostWarning)
                    run = localize_scans(
                        m.spec, m.probability, batch.times, batch.ranges, angles, odo,
                        batch.max_range, cfg, start=start, stop=stop,
                        laser_offset=mount, progress=tick, observer=observer,
                    )  # fmt: skip
            except BaseException:
                if observer is not None:
                    observer.view.close(keep=False)
                raise
        if run.ended_lost and not allow_lost:
            if observer is not None:
                observer.view.close(keep=False)
            raise CliError(
                f"{log}: {run.episodes[-1].describe()} and did not recover; nothing written "
                "(--allow-lost writes the trajectory anyway)"
            )
        errors = None
        if ref_t is not None and ref_p is not None:
            errors = trajectory_errors(run, ref_t, ref_p, laser=True)
            if errors[0].size == 0 and reference is None:
                errors = None  # a session's scans outside the localized part: no table
            elif errors[0].size == 0:
                if observer is not None:
                    observer.view.close(keep=False)
                raise CliError("no update coincides with a reference pose")
        rows = np.column_stack([run.times, run.poses, run.spread])
        traj = output / "trajectory.csv"
        plot = output / "trajectory.png"
        from probmap.viz.localize import save_localization_figure

        extra: list[Path] = []
        with watch("write"):
            try:
                with atomic_outputs():  # every file or none; a missing folder is created
                    with atomic_path(traj) as tmp:
                        np.savetxt(
                            tmp, rows, delimiter=",", fmt="%.6f", header="time,x,y,theta,spread",
                            comments="",
                        )  # fmt: skip
                    save_localization_figure(
                        plot, m, run.times, run.poses, run.spread,
                        reference=None if ref_t is None else (ref_t, ref_p),
                        particles=run.particles, title=f"MCL: {log.name} in {map_path.name}",
                        converged=(
                            run.times.size if run.converged_index is None else run.converged_index
                        ),
                    )  # fmt: skip
                    if tum:
                        from probmap.datasets.tum import write_tum

                        extra.append(write_tum(output / "trajectory.tum", run.times, run.poses))
                    extra.append(write_run_config(output / "config.yaml", cfg))
            except BaseException:
                if observer is not None:
                    observer.view.close(keep=False)
                raise
            if observer is not None:
                observer.view.close()

        console = Console()
        summary_rows = [
            # the file read (a folder's slam.session named), not only what was given
            ("map", f"{m.source} ({m.kind}, {m.spec.shape[1]} x {m.spec.shape[0]} cells)"),
            *input_rows(batch.readings, batch.skipped_lines),
            ("laser offset", _describe_offset(mount)),
            *([offset_row] if offset_row is not None else []),
            ("updates", f"{run.times.size:,}"),
            *_particle_rows(run, cfg),
            ("final spread", f"{run.spread[-1]:.3f} m" if run.spread.size else "-"),
            *_convergence_rows(run, cfg.global_localization),
            *[("lost", e.describe()) for e in run.episodes],
            watch.row(),
            ("wrote", ", ".join(str(f) for f in (traj, plot, *extra))),
            *recorded_rows(viz_save),
        ]
        print_summary(f"probmap localize {log.name}", summary_rows, console=console)
        if errors is not None:
            err, head = errors
            table = Table(title=f"error against {ref_name}")
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
    app.command("localize", short_help="Localize the robot of a laser log on a map with MCL.")(
        localize_command
    )
