"""``probmap slam grid`` (grid SLAM from a raw log) and ``probmap match`` (one scan on a map)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from probmap.cli import options as opt
from probmap.cli._provenance import command_line
from probmap.cli.common import (
    check_choice,
    cli_errors,
    input_rows,
    laser_input,
    print_summary,
    resolve_config,
)
from probmap.cli.landmark_slam import slam_app
from probmap.cli.watch import (
    interrupted_exit,
    open_view,
    save_partial_option,
    stop_on_ctrl_c,
    view_discarded_on_error,
    viz_option,
    viz_save_option,
)


@slam_app.command("grid", short_help="Grid SLAM of a laser log or bag: graph (default) or RBPF.")
@opt.with_option_groups
def grid_command(
    log: Path = typer.Argument(
        ..., help="A raw CARMEN log (plain, .gz or .bz2), a ROS 1/2 bag or a dataset name."
    ),
    output: str = opt.output_option(
        "Output prefix (PREFIX.yaml, ...); an existing folder (or a name ending in /) "
        "writes FOLDER/slam.*. Missing folders are created."
    ),
    method: str = typer.Option(
        "graph",
        "--method",
        help="graph: submaps, loop closure and pose-graph optimization (default); "
        "rbpf: Rao-Blackwellized particle filter.",
    ),
    end_time: float | None = typer.Option(
        None, "--end-time", help="Use only the first this many seconds of the log."
    ),
    bag_options: dict[str, Any] = opt.ros_bag_options(),
    data_dir: Path | None = opt.data_dir_option(),
    config: Path | None = opt.config_option(
        "A YAML configuration: SubmapSlamConfig fields (graph) or RbpfConfig fields "
        "(rbpf; the options below override it). Fields left out keep their defaults."
    ),
    particles: int | None = opt.particles_option("rbpf: number of particles [default: 30]."),
    linear_update: float | None = typer.Option(
        None,
        "--linear-update",
        help="rbpf: process a scan after this many metres of travel [default: 0.5].",
    ),
    angular_update: float | None = typer.Option(
        None,
        "--angular-update",
        help="rbpf: ... or after this many radians of rotation [default: 0.25].",
    ),
    seed: int | None = opt.seed_option("rbpf: random seed [default: 0]."),
    guard: bool | None = typer.Option(
        None,
        "--guard/--no-guard",
        help="rbpf: keep the odometry along featureless corridors [default: guard].",
    ),
    skip_bad_lines: bool = opt.skip_bad_lines_option(),
    viz: bool = viz_option("graph: watch the run in the rerun viewer (extra 'viz')."),
    viz_save: Path | None = viz_save_option(
        "graph: record the live view into FILE.rrd (open it later with 'rerun FILE.rrd')."
    ),
    tum: bool = opt.tum_option(
        "Also write PREFIX.tum: the trajectory in the TUM format (evo_ape, evo_rpe)."
    ),
    save_partial: bool = save_partial_option(
        "graph: on Ctrl-C, finish with the scans so far and write their map and trajectory "
        "(exit 130); a second Ctrl-C aborts without writing."
    ),
    save_session: Path | None = typer.Option(
        None,
        "--save-session",
        help="graph: also write the run's state to FILE (a folder: FOLDER/slam.session), to "
        "continue it later with --resume (arrays and a JSON header: docs/sessions.md). After "
        "Ctrl-C it holds the scans so far.",
    ),
    odometry: bool | None = typer.Option(
        None,
        "--odometry/--no-odometry",
        help="graph: use the log's odometry, or ignore it and predict each scan's motion "
        "from the last one (lidar-only SLAM) [default: odometry when the log has any].",
    ),
    resume: Path | None = typer.Option(
        None,
        "--resume",
        help="graph: continue the session saved in FILE (a folder: FOLDER/slam.session) with "
        "this log, in the same odometry frame: the log that continues it, or its own log "
        "after an interrupted run (the scans it holds are skipped); the outputs cover the "
        "whole session.",
    ),
) -> None:
    """Grid SLAM from a raw log or ROS bag: writes the map (PREFIX.yaml/.pgm/.npz/.png, as
    'probmap map'), PREFIX.trajectory.csv (robot pose at every scan time) and, for the graph
    method, the pose graph PREFIX.g2o and PREFIX.plot.png (map, trajectory, loop closures), and
    PREFIX.config.yaml (the configuration used, with the probmap version); with --tum also
    PREFIX.tum, the trajectory in the TUM format that evo reads."""
    from probmap.cli.common import Stopwatch

    watch = Stopwatch()  # the summary time covers the whole command
    with cli_errors():
        check_choice("--method", method, ("graph", "rbpf"))
        log = laser_input(log, data_dir)
        from probmap.pipelines import check_output_prefix

        prefix = check_output_prefix(output, "slam")
        rbpf_options = {
            "particles": particles,
            "linear_update": linear_update,
            "angular_update": angular_update,
            "seed": seed,
            "degeneracy_guard": guard,
        }
        flags = {"particles": "--particles", "linear_update": "--linear-update",
                 "angular_update": "--angular-update", "seed": "--seed",
                 "degeneracy_guard": "--guard/--no-guard"}  # fmt: skip
        given = [flags[k] for k, v in rbpf_options.items() if v is not None]
        if method == "graph" and given:
            raise ValueError(
                f"{', '.join(given)} {'is' if len(given) == 1 else 'are'} for the RBPF: add "
                "--method rbpf (graph SLAM, the default, has no particles)"
            )
        if method == "rbpf" and (viz or viz_save is not None):
            raise ValueError("--viz and --viz-save watch the graph method (--method graph)")
        if method == "rbpf" and (save_session is not None or resume is not None):
            raise ValueError("--save-session and --resume are for the graph method")
        if method == "rbpf" and odometry is not None:
            raise ValueError("--odometry and --no-odometry are for the graph method")
        _slam_grid(
            log, prefix, method, rbpf_options, end_time, bag_options, config,
            skip_bad_lines=skip_bad_lines, viz=viz, viz_save=viz_save,
            save_partial=save_partial, tum=tum, save_session=save_session, resume=resume,
            watch=watch, odometry=odometry,
        )  # fmt: skip


def _slam_grid(
    log: Path,
    prefix: Path,
    method: str,
    rbpf_options: dict[str, Any],
    end_time: float | None,
    bag_options: dict,
    config: Path | None,
    *,
    skip_bad_lines: bool,
    viz: bool,
    viz_save: Path | None,
    save_partial: bool,
    tum: bool,
    save_session: Path | None,
    resume: Path | None,
    watch: Any,
    odometry: bool | None = None,
) -> None:
    """Resolve the configuration, set up the progress bar, live view and Ctrl-C handling,
    call :func:`probmap.pipelines.laser_slam.slam_grid` and print its summary."""
    import warnings
    from contextlib import nullcontext

    from probmap.cli.common import note_first_compile, progress_bar
    from probmap.errors import BadLinesWarning
    from probmap.pipelines.laser_slam import SESSION_NAME, slam_grid

    session = None
    session_info = None
    if method == "graph":
        from probmap.slam.laser.submap_slam import SubmapSlamConfig

        # a folder names its default file, as -o does (issue 20's output rule)
        if save_session is not None and save_session.is_dir():
            save_session = save_session / SESSION_NAME
        if resume is not None and resume.is_dir():
            resume = resume / SESSION_NAME
        if resume is not None:
            from probmap.pipelines.sessions import load_session, read_session_info

            if config is not None:
                raise ValueError(
                    "--resume continues with the session's own configuration; no --config"
                )
            session_info = read_session_info(resume)
            session = load_session(resume)
            cfg: Any = None
        else:
            cfg = resolve_config(SubmapSlamConfig, config)
        if save_session is not None:
            from probmap.pipelines import check_output_folder

            check_output_folder(save_session.parent if str(save_session.parent) else Path("."))
        note_first_compile(
            "probmap.slam.laser._match_kernels",
            "probmap.slam.laser._bnb_kernels",
            "probmap.slam.posegraph._kernels",
        )
    else:
        from probmap.slam.laser.rbpf import RbpfConfig

        cfg = resolve_config(RbpfConfig, config, rbpf_options)
    observer = None
    view = open_view(f"probmap slam grid {log.name}", viz, viz_save)
    if view is not None:
        from probmap.viz.live import GraphSlamObserver

        observer = GraphSlamObserver(view)
    title = "graph SLAM" if method == "graph" else "grid SLAM"
    with (
        progress_bar(f"{title} {log.name}", unit="scans") as bar,
        warnings.catch_warnings(record=True) as caught,
    ):
        warnings.simplefilter("always")  # each shown once, as one line, after the run
        # the summary reports skipped lines; no Python warning text on the terminal
        warnings.simplefilter("ignore", BadLinesWarning)
        task = bar.add_task(log.name, total=0)

        def tick(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        stopping = stop_on_ctrl_c(save_partial, unit="scan") if method == "graph" else nullcontext()
        with view_discarded_on_error(view), stopping as stop:
            out = slam_grid(
                log, prefix, cfg, end_time=end_time, bag_options=bag_options,
                skip_bad_lines=skip_bad_lines, resume=session, resume_info=session_info,
                save_session=save_session,
                tum=tum, command=command_line(), title=log.name, progress=tick,
                observer=observer, stop=stop, phase=watch, odometry=odometry,
            )  # fmt: skip
        if observer is not None:
            observer.view.close()
    for w in caught:
        typer.echo(f"warning: {w.message}", err=True)
    if method == "graph":
        asked = stop is not None and stop()  # a Ctrl-C during the last scan ends no earlier
        _graph_summary(out, watch, resume, viz_save, asked=asked, prefix=prefix)
    else:
        _rbpf_summary(out, watch, cfg.particles)


def _graph_summary(
    out: Any,
    watch: Any,
    resume: Path | None,
    viz_save: Path | None,
    *,
    asked: bool = False,
    prefix: Path | None = None,
) -> None:
    run = out.run
    spec = run.grid.spec
    weights = run.closure_weights
    rows = [
        ("scans", f"{len(run.times):,}"),
        *input_rows(out.readings, out.skipped_lines),
        *(
            [("resumed", f"{resume}: {run.scans_total - out.scans_read:,} scans before this log")]
            if resume is not None and not out.scans_skipped
            else [
                (
                    "resumed",
                    f"{resume}: {run.scans_total - out.scans_read:,} scans, the first "
                    f"{out.scans_skipped:,} of this log among them",
                )
            ]
            if resume is not None
            else []
        ),
        ("nodes", f"{run.nodes:,}"),
        ("submaps", f"{run.submaps:,}"),
        (
            "loop closures",
            f"{len(weights) - int(run.slam.loops.left_out.sum()):,} accepted of "
            f"{run.searched:,} searched "
            f"({int((weights >= 0.5).sum()):,} kept by the robust cost)",
        ),
        *_check_rows(out.report),
        ("map", f"{spec.width} x {spec.height} cells at {spec.resolution:g} m"),
        ("optimization", f"{run.optimize_seconds:.1f} s"),
        _time_row(watch, run.duration, run.seconds),
        ("peak memory", f"{out.peak_rss_mib:.0f} MiB"),
    ]
    rows += [("wrote", str(f)) for f in out.files]
    if viz_save is not None:
        rows.append(("recorded", f"{viz_save} (rerun {viz_save})"))
    if run.interrupted or asked:
        rows.insert(1, ("interrupted", f"at scan {len(run.times):,} of {run.scans_total:,}"))
    print_summary("grid SLAM (graph)", rows)
    if out.report is not None and prefix is not None:
        from probmap.pipelines.laser_slam import doubt_line

        line = doubt_line(out.report.get("doubts", []), prefix)
        if line is not None:
            typer.echo(f"warning: {line}", err=True)
    if run.interrupted or asked:
        interrupted_exit(len(run.times), run.scans_total, "scans", wrote=True)


def _check_rows(report: dict[str, Any] | None) -> list[tuple[str, str]]:
    """The summary rows of the closure report and the self-consistency check."""
    if report is None:
        return []
    rejected = report["closures"]["rejected"]
    share = report["consistency"]["share"]
    overridden = report["local"]["odometry_overridden_s"]
    if report["local"].get("lidar_only"):
        lost = report["local"]["untracked_s"]
        local = f"no odometry: lidar only, {len(lost):,} scans matched nothing"
        if report["local"].get("scans_reordered"):
            local += (
                f", {report['local']['scans_reordered']:,} scans taken in the order they were "
                "published"
            )
        shown_t = lost
    else:
        local = f"overrode the odometry {len(overridden):,} times"
        shown_t = overridden
    if shown_t:
        shown = ", ".join(f"{t:.0f}" for t in shown_t[:6])
        local += f" (t = {shown}{', ...' if len(shown_t) > 6 else ''} s)"
    return [
        ("local SLAM", local),
        (
            "closures rejected",
            f"{rejected['not_confirmed_by_earlier_nodes']:,} not confirmed, "
            f"{rejected['correction_beyond_drift_bound']:,} beyond the drift bound, "
            f"{rejected['ambiguous_place']:,} ambiguous, "
            f"{rejected.get('inconsistent_with_other_closures', 0):,} inconsistent",
        ),
        ("consistency", f"{share:.2%} of the walls seen were open space to other visits"),
        *_revisit_rows(report.get("revisits")),
        ("doubtful places", _doubt_row(report.get("doubts", []))),
    ]


def _revisit_rows(revisits: dict[str, Any] | None) -> list[tuple[str, str]]:
    """The summary's row of revisited places and how many no closure joined (none for a
    report without them)."""
    if not revisits:
        return []
    if not revisits["pieces"]:
        return [("revisits", "none (no place passed again after 30 m of travel)")]
    step = revisits["piece_m"]
    seen, loose = revisits["pieces"] * step, revisits["unjoined_pieces"] * step
    return [("revisits", f"{seen:,.0f} m of travel passed mapped places, {loose:,.0f} m of it "
             "joined by no loop closure")]  # fmt: skip


def _doubt_row(doubts: list[dict[str, Any]]) -> str:
    """The summary's row of places and times where the map may be wrong."""
    places = [d for d in doubts if d["kind"] == "walls_in_open_space"]
    lost = [d for d in doubts if d["kind"] == "untracked"]
    if not doubts:
        return "none"
    parts = []
    if places:
        shown = ", ".join(f"{d['walls_seen_s'][0]:.0f}/{d['open_space_seen_s'][0]:.0f}"
                          for d in places[:4])  # fmt: skip
        parts.append(f"{len(places)} (visits at t = {shown}{', ...' if len(places) > 4 else ''} s)")
    twice = [d for d in doubts if d["kind"] == "unjoined_revisit"]
    if twice:
        shown = ", ".join(f"{d['start_s']:.0f}-{d['end_s']:.0f}" for d in twice[:4])
        more = ", ..." if len(twice) > 4 else ""
        parts.append(f"{len(twice)} revisit(s) no closure joined (t = {shown}{more} s)")
    if lost:
        parts.append(f"{len(lost)} span(s) of scans that matched nothing")
    return "; ".join(parts)


def _time_row(watch: Any, duration: float, seconds: float) -> tuple[str, str]:
    """The summary's time row: the whole command split into its phases, and how much faster
    than the log's own duration the SLAM itself ran."""
    name, value = watch.row()
    if duration > 0:
        return name, f"{value}, SLAM {duration / max(seconds, 1e-9):.1f}x real time"
    return name, f"{value} (the log has no timestamps: no real-time factor)"


def _rbpf_summary(out: Any, watch: Any, particles: int) -> None:
    result = out.run
    duration = float(result.times[-1] - result.times[0])
    spec = result.grid.spec
    rows = [
        ("scans", f"{len(result.times):,} ({result.processed:,} processed)"),
        *input_rows(out.readings),
        ("particles", f"{particles} ({result.resamples} resamplings)"),
        ("failed matches", f"{result.failed_matches:,}"),
        ("map", f"{spec.width} x {spec.height} cells at {spec.resolution:g} m"),
        ("map tiles", f"{result.map_bytes / 2**20:.1f} MiB (peak)"),
        _time_row(watch, duration, result.seconds),
    ]
    rows += [("wrote", str(f)) for f in out.files]
    print_summary("grid SLAM (rbpf)", rows)


@opt.with_option_groups
def match_command(
    map_file: Path = typer.Argument(..., help="A map: PREFIX.npz or a map_server PREFIX.yaml."),
    log: Path = typer.Argument(
        ..., help="The log holding the scan: CARMEN, ROS 1/2 bag or a dataset name."
    ),
    scan: int = typer.Option(0, "--scan", help="Index of the front-laser scan in the log."),
    x: float | None = typer.Option(None, "--x", help="Initial x (m); default the log's pose."),
    y: float | None = typer.Option(None, "--y", help="Initial y (m)."),
    theta: float | None = typer.Option(None, "--theta", help="Initial heading (rad)."),
    sigma: float | None = typer.Option(
        None, "--sigma", help="Match field width (m) [default: 0.05]."
    ),
    window: float | None = typer.Option(
        None, "--window", help="Search half-width in x and y (m) [default: 0.3]."
    ),
    angular_window: float | None = typer.Option(
        None, "--angular-window", help="Search half-width in heading (rad) [default: 0.2]."
    ),
    config: Path | None = opt.config_option(
        "A YAML file of MatcherConfig fields (sigma, linear_window, linear_step, "
        "angular_window, angular_step, iterations, usable_range, beam_skip) over the defaults "
        "above; the options given here override it."
    ),
    skip_bad_lines: bool = opt.skip_bad_lines_option(),
    bag_options: dict[str, Any] = opt.ros_bag_options(),
    data_dir: Path | None = opt.data_dir_option(),
) -> None:
    """Match one scan of a log against a map: prints the pose, its standard deviations and
    the match score (correlative search refined by Gauss-Newton)."""
    with cli_errors():
        import numpy as np

        from probmap.cli._provenance import config_over
        from probmap.cli.common import Stopwatch
        from probmap.datasets.scans import open_scans
        from probmap.slam.laser.scan_matching import (
            MatcherConfig,
            MatchField,
            match_scan,
            scan_points,
        )

        watch = Stopwatch()
        if not map_file.exists():
            raise FileNotFoundError(f"{map_file}: no such file")
        log = laser_input(log, data_dir)
        # the command's own search window is wider than MatcherConfig's (one scan, no motion)
        base = MatcherConfig(sigma=0.05, linear_window=0.3, angular_window=0.2)
        options = {"sigma": sigma, "linear_window": window, "angular_window": angular_window}
        cfg = config_over(base, config, options)
        suffix = map_file.suffix.lower()
        if suffix not in (".npz", ".yaml", ".yml"):
            raise ValueError(f"{map_file}: expected a .npz or map_server .yaml map")
        import warnings

        from probmap.datasets.validate import require_usable, validate_ranges
        from probmap.errors import BadLinesWarning

        with watch("read"):
            if suffix == ".npz":
                from probmap.grid.io import load_npz

                grid = load_npz(map_file)
            else:
                from probmap.grid.io import read_map_server

                m = read_map_server(map_file)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", BadLinesWarning)  # counted in the summary
                batch = open_scans(
                    log,
                    poses="corrected",
                    skip_bad_lines=skip_bad_lines,
                    bag_options=bag_options,
                )
        with watch("compute"):
            if suffix == ".npz":
                field = MatchField.from_grid(grid, cfg.sigma)
            else:
                occ = np.nan_to_num(m.probability, nan=0.0) > m.occupied_thresh
                field = MatchField.from_occupied(occ, m.spec, cfg.sigma)
            n = len(batch.times)
            if not 0 <= scan < n:
                raise ValueError(f"--scan must lie in 0..{n - 1} for {log}, got {scan}")
            _, one = validate_ranges(
                batch.ranges[scan : scan + 1], batch.max_range, beams=batch.beams[scan : scan + 1]
            )
            require_usable(one, f"{log}, scan {scan}", batch.max_range)
            angles = np.asarray(batch.angles)
            angles = angles if angles.ndim == 1 else angles[scan]
            guess = np.asarray(batch.laser_poses[scan], dtype=np.float64).copy()
            for i, v in enumerate((x, y, theta)):
                if v is not None:
                    guess[i] = v
            pts = scan_points(batch.ranges[scan], angles, float(batch.max_range), cfg.usable_range)
            res = match_scan(field, pts, guess, cfg)
        sd = np.sqrt(np.diag(res.covariance))
        print_summary(
            f"scan {scan} of {log.name} on {map_file.name}",
            [
                ("initial", f"x={guess[0]:.3f} y={guess[1]:.3f} theta={guess[2]:.4f}"),
                (
                    "matched",
                    f"x={res.pose[0]:.3f} y={res.pose[1]:.3f} theta={res.pose[2]:.4f}",
                ),
                ("std dev", f"x={sd[0]:.4f} m y={sd[1]:.4f} m theta={sd[2]:.5f} rad"),
                ("score", f"{res.score:.3f} ({res.points} endpoints)"),
                *input_rows(batch.readings, batch.skipped_lines),
                (
                    "matcher",
                    f"sigma {cfg.sigma:g} m, window {cfg.linear_window:g} m / "
                    f"{cfg.angular_window:g} rad",
                ),
                watch.row(),
            ],
        )


def register(app: typer.Typer) -> None:
    """Add ``match`` to ``app`` (``slam grid`` is on :data:`slam_app`)."""
    app.command("match", short_help="Match one scan of a log against a map.")(match_command)
