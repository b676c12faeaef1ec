"""``probmap slam ...`` (landmark SLAM).

The SEIF commands are added to :data:`slam_app` by :mod:`probmap.cli.seif`; the helpers
:func:`read_landmark_dataset`, :func:`limit_threads`, :func:`run_and_report` and the options are
shared with it.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import typer

from probmap.cli import options as opt
from probmap.cli._provenance import command_line
from probmap.cli.common import CliError, Stopwatch, cli_errors, print_summary
from probmap.cli.watch import (
    interrupted_exit,
    live_view_options,
    open_view,
    recorded_rows,
    stop_on_ctrl_c,
    view_discarded_on_error,
)

slam_app = typer.Typer(
    help="Landmark SLAM on feature datasets (EKF; SEIF; GraphSLAM).", no_args_is_help=True
)

DATASET_HELP = (
    "A registered name (see 'probmap datasets list'), or a path whose format is guessed: an "
    "MRCLAM folder, a Victoria Park folder."
)


# the arguments and options every landmark-SLAM command shares (one definition each)
def dataset_argument() -> Any:
    return typer.Argument(..., help=DATASET_HELP)


def output_folder_option() -> Any:
    """``-o/--output``: the folder :func:`run_and_report` writes into."""
    return opt.output_option("Output folder (created when missing).")


def estimator_config_option(config: str, then: str) -> Any:
    """``--config``: a YAML file of the estimator's ``config`` as :func:`run_and_report` records
    it in OUTPUT/config.yaml; ``then`` says what it replaces or what overrides it."""
    return opt.config_option(f"A YAML file of {config} (as OUTPUT/config.yaml records it){then}")


def data_dir_option() -> Any:
    return typer.Option(
        None, "--data-dir", help="Data directory for registered names (default $PROBMAP_DATA)."
    )


def robot_option() -> Any:
    return typer.Option(1, "--robot", help="MRCLAM robot number (1-5).")


def end_time_option() -> Any:
    return typer.Option(None, "--end-time", help="Stop after this many seconds of data.")


def threads_option() -> Any:
    return typer.Option(1, "--threads", help="BLAS threads.")


def plot_option() -> Any:
    return typer.Option(True, "--plot/--no-plot", help="Write slam.png.")


UNKNOWN_HELP = "Ignore given landmark ids: maximum-likelihood association."


def unknown_option(help: str = UNKNOWN_HELP) -> Any:
    """``--unknown``: the estimator associates the observations itself (``help`` says how)."""
    return typer.Option(False, "--unknown", help=help)


@dataclass(frozen=True)
class LandmarkSource:
    """Where a landmark command's data come from: ``--data-dir``, ``--robot``, ``--unknown``
    and ``--end-time``, as one parameter (:func:`landmark_source_options`).

    Attributes
    ----------
    data_dir : Path or None
        Data directory for registered names (None: ``$PROBMAP_DATA``).
    robot : int
        MRCLAM robot number (1-5).
    unknown : bool
        Ignore the dataset's landmark ids (the estimator associates the observations).
    end_time : float or None
        Stop after this many seconds of data (None: the whole log).
    """

    data_dir: Path | None
    robot: int
    unknown: bool
    end_time: float | None


def landmark_source_options(unknown_help: str = UNKNOWN_HELP) -> Any:
    """The four options every landmark command reads its dataset with, as one
    :class:`LandmarkSource` (an :func:`~probmap.cli.options.option_group`; ``unknown_help``
    says how the command associates without ids)."""
    return opt.option_group(
        LandmarkSource,
        data_dir=(Path | None, data_dir_option()),
        robot=(int, robot_option()),
        unknown=(bool, unknown_option(unknown_help)),
        end_time=(float | None, end_time_option()),
    )


def report_options() -> Any:
    """``--plot/--no-plot``, ``--tum`` and the live view's options (:func:`live_view_options`):
    what every landmark command writes and shows, as one dict of :func:`run_and_report`'s
    keywords (an :func:`~probmap.cli.options.option_group`)."""
    live = {name: (ann, option) for name, ann, option in live_view_options().options}
    return opt.option_group(dict, plot=(bool, plot_option()), tum=(bool, opt.tum_option()), **live)


def limit_threads(threads: int) -> None:
    """Cap BLAS threads before numpy loads (small dense updates run faster single-threaded)."""
    if "numpy" not in sys.modules:
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(var, str(threads))


def open_landmark_dataset(
    dataset: str,
    data_dir: Path | None,
    robot: int,
    unknown: bool,
    end_time: float | None,
) -> Any:
    """Load a landmark dataset by name or path, passing only the options its reader takes."""
    from probmap.datasets import registry

    info = registry.DATASETS.get(dataset)
    fmt = info.format if info is not None else registry.guess_format(dataset)
    if info is not None and info.kind != "landmarks":
        raise CliError(f"dataset {dataset!r} is a {info.kind} dataset, not a landmark dataset")
    opts: dict[str, Any] = {}
    if fmt == "mrclam":
        opts = {"robot": robot, "known": not unknown, "end_time": end_time}
    elif fmt == "victoria-park":
        opts = {"end_time": end_time}
    elif fmt == "simulation":
        opts = {"known_correspondences": not unknown}
    else:
        raise CliError(f"{dataset}: format {fmt!r} holds no landmark observations")
    return registry.load(dataset, data_directory=data_dir, **opts)


def read_landmark_dataset(
    watch: Stopwatch, output: Path | None, dataset: str, source: LandmarkSource
) -> Any:
    """The steps every landmark-SLAM command takes once its configuration is known: check
    the ``output`` folder (when it writes one) before any work, then read the dataset
    (:func:`open_landmark_dataset`) as the ``read`` phase of the command's ``watch``."""
    if output is not None:
        from probmap.pipelines import check_output_folder

        check_output_folder(output)
    with watch("read"):
        return open_landmark_dataset(
            dataset, source.data_dir, source.robot, source.unknown, source.end_time
        )


def _fmt(v: Any, unit: str = "") -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.3f}{unit}"
    return f"{v}{unit}"


def metrics_rows(m: dict[str, Any]) -> list[tuple[str, str]]:
    """The headline figures of a metrics dict as (label, value) rows."""
    rows = [
        ("steps", f"{m['steps']:,}"),
        ("observations", f"{m['observations']:,}"),
        ("landmarks mapped", f"{m['landmarks_mapped']:,}"),
        ("time", f"{m['time_s']:.2f} s ({m['step_ms']['mean']:.3f} ms/step mean)"),
    ]
    pairs = [
        ("ATE RMSE", "ate", "translation_m"),
        ("ATE RMSE (SE(2)-aligned)", "ate_aligned", "translation_m"),
        ("dead reckoning ATE RMSE", "dead_reckoning_ate", "translation_m"),
        ("landmark RMSE", "landmarks", "error_m"),
        ("landmark RMSE (aligned)", "landmarks_aligned", "error_m"),
    ]
    for label, key, sub in pairs:
        if key in m:
            rows.append((label, _fmt(m[key][sub]["rmse"], " m")))
    for label, key in (("GPS RMSE", "gps"), ("dead reckoning GPS RMSE", "dead_reckoning_gps")):
        if key in m:
            g = m[key]
            rows.append(
                (
                    label,
                    f"{g['rmse_m']:.3f} m ({g['fixes_used']} fixes, "
                    f"{g['fixes_rejected_as_jumps']} jumps rejected)",
                )
            )
    if "pose_nees" in m:
        rows.append(("pose NEES mean", _fmt(m["pose_nees"]["mean"])))
    if "nis" in m:
        rows.append(("NIS per dof", _fmt(m["nis"]["mean_per_dof"])))
    return rows


def _provenance(estimator: Any) -> dict[str, Any]:
    """What metrics.json records of the run itself: the probmap version, the command line and
    the estimator's configuration (its frozen config dataclass, when it has one; JSON has no
    infinity, so config.yaml beside it is the exact, loadable copy)."""
    import dataclasses
    import sys

    from probmap import __version__

    out: dict[str, Any] = {"probmap_version": __version__, "command": " ".join(sys.argv)}
    cfg = getattr(estimator, "config", None)
    if dataclasses.is_dataclass(cfg) and not isinstance(cfg, type):
        import yaml

        from probmap.config import dump_config

        out["configuration"] = yaml.safe_load(dump_config(cfg))
    return out


def run_and_report(
    estimator: Any,
    dataset: Any,
    output: Path,
    title: str,
    plot: bool,
    *,
    tum: bool = False,
    watch: Stopwatch | None = None,
    viz: bool = False,
    viz_save: Path | None = None,
    save_partial: bool = True,
) -> dict[str, Any]:
    """Run with a progress bar, evaluate, write outputs and a plot (all or none; with ``tum``
    also ``trajectory.tum``), print the metrics table.

    ``watch`` is the command's stopwatch (started before the dataset was read, so that the
    summary time covers the whole command); ``viz``/``viz_save`` show or record the run
    (:class:`probmap.viz.live.LandmarkSlamObserver`). Ctrl-C stops after the current step:
    with ``save_partial`` the outputs of the steps so far are written, then the command exits
    with code 130 (without it, or on a second Ctrl-C, nothing is written)."""
    import dataclasses

    from probmap._atomic import atomic_outputs
    from probmap.cli.common import progress_bar
    from probmap.pipelines import check_output_folder
    from probmap.pipelines.landmark_slam import evaluate, run_landmark_slam, write_slam_outputs

    watch = watch or Stopwatch()
    check_output_folder(output)
    view = open_view(f"probmap {title} on {getattr(dataset, 'name', '')}", viz, viz_save)
    observer = None
    if view is not None:
        from probmap.viz.live import LandmarkSlamObserver

        gt = getattr(dataset, "gt_trajectory", None)
        observer = LandmarkSlamObserver(view, dataset.measurement_model, reference=gt)
    # the time so far outside the phases: imports (numba kernels loaded), checks, the viewer
    watch.phases = {"setup": watch.total - sum(watch.phases.values()), **watch.phases}
    with view_discarded_on_error(view):
        with watch("compute"):
            with progress_bar(title, unit="steps") as bar, stop_on_ctrl_c(save_partial) as stop:
                task = bar.add_task(title, total=len(dataset))
                result = run_landmark_slam(
                    estimator,
                    dataset,
                    progress=lambda i, n: bar.update(task, completed=i),
                    observer=observer,
                    stop=stop,
                )
            with progress_bar(unit="runs") as bar:
                bar.add_task(f"evaluating {len(result.trajectory):,} steps", total=1)
                metrics = evaluate(result, dataset)
    metrics["dataset"] = getattr(dataset, "name", "")
    metrics["estimator"] = title
    metrics.update(_provenance(estimator))
    if result.interrupted:
        metrics["interrupted"] = {"steps": len(result.trajectory), "of": result.steps_total}
    with watch("write"), progress_bar(unit="parts") as bar:
        task = bar.add_task(f"writing {output}", total=2 + tum + plot)
        with view_discarded_on_error(view):
            if observer is not None:
                observer.finish(result, dataset, metrics)
            with atomic_outputs():  # a missing folder is created; a failed picture leaves no CSV
                files = write_slam_outputs(result, metrics, output)
                cfg = getattr(estimator, "config", None)
                if dataclasses.is_dataclass(cfg) and not isinstance(cfg, type):
                    from probmap.config import write_config

                    files.append(  # exact, loadable
                        write_config(output / "config.yaml", cfg, command=command_line())
                    )
                bar.advance(task, 2)
                if tum:
                    from probmap.datasets.tum import write_tum

                    tr = result.trajectory
                    files.append(write_tum(output / "trajectory.tum", tr[:, 0], tr[:, 1:4]))
                    bar.advance(task)
                if plot:
                    from probmap.viz.landmark_slam import save_slam_figure

                    files.append(
                        save_slam_figure(
                            output / "slam.png", result, dataset, title=title, metrics=metrics
                        )
                    )
        if view is not None:
            view.close()
    rows = metrics_rows(metrics)
    rows = [r for r in rows if r[0] != "time"]
    steps = metrics["step_ms"]
    rows.append(("step time", f"{steps['mean']:.3f} ms mean, {steps['median']:.3f} ms median"))
    rows.append(watch.row())
    rows += [("wrote", str(f)) for f in files]
    rows += recorded_rows(viz_save)
    if result.interrupted:
        done = len(result.trajectory)
        rows.insert(0, ("interrupted", f"at step {done:,} of {result.steps_total:,}"))
    print_summary(f"{title} on {metrics['dataset']}", rows)
    if result.interrupted:
        interrupted_exit(len(result.trajectory), result.steps_total, "steps", wrote=True)
    return metrics


@slam_app.command("ekf")
@opt.with_option_groups
def ekf_command(
    dataset: str = dataset_argument(),
    output: Path = output_folder_option(),
    source: LandmarkSource = landmark_source_options(),
    threads: int = threads_option(),
    config: Path | None = estimator_config_option(
        "the estimator's configuration", " instead of the dataset's defaults."
    ),
    report: dict[str, Any] = report_options(),
) -> None:
    """EKF SLAM (Probabilistic Robotics Table 10.1/10.2): writes trajectory.csv, landmarks.csv,
    metrics.json and slam.png (and trajectory.tum with --tum) into OUTPUT."""
    watch = Stopwatch()
    limit_threads(threads)
    with cli_errors():
        from probmap.config import load_config
        from probmap.pipelines.landmark_slam import default_ekf_config
        from probmap.slam.landmark.ekf import EKFConfig, build_ekf

        file_cfg = None if config is None else load_config(EKFConfig, config)
        ds = read_landmark_dataset(watch, output, dataset, source)
        ekf = build_ekf(ds, file_cfg if file_cfg is not None else default_ekf_config(ds))
        run_and_report(ekf, ds, output, "EKF SLAM", watch=watch, **report)


@slam_app.command("graphslam")
@opt.with_option_groups
def graphslam_command(
    dataset: str = dataset_argument(),
    output: Path = output_folder_option(),
    source: LandmarkSource = landmark_source_options(
        "Ignore given landmark ids: Table 11.9's correspondence test (small maps only)."
    ),
    robust: str = typer.Option(
        "none", "--robust", help="Robust kernel on the measurements: none, huber or cauchy."
    ),
    threads: int = threads_option(),
    config: Path | None = estimator_config_option(
        "GraphSLAMConfig", " instead of the dataset's defaults; --robust still applies."
    ),
    report: dict[str, Any] = report_options(),
) -> None:
    """GraphSLAM over the whole log (Probabilistic Robotics Tables 11.1-11.5, known landmark
    ids): writes trajectory.csv (smoothed), landmarks.csv, metrics.json and slam.png (and
    trajectory.tum with --tum) into OUTPUT, like 'probmap slam ekf'."""
    watch = Stopwatch()
    limit_threads(threads)
    with cli_errors():
        from dataclasses import replace

        from probmap.config import load_config
        from probmap.pipelines.landmark_slam import default_graphslam_config
        from probmap.slam.landmark.graphslam import GraphSLAMConfig, build_graphslam

        file_cfg = None if config is None else load_config(GraphSLAMConfig, config)
        ds = read_landmark_dataset(watch, output, dataset, source)
        base = file_cfg if file_cfg is not None else default_graphslam_config(ds)
        gcfg = replace(base, robust=robust, robust_scale=None)
        run_and_report(build_graphslam(ds, gcfg), ds, output, "GraphSLAM", watch=watch, **report)


@slam_app.command("fastslam")
@opt.with_option_groups
def fastslam_command(
    dataset: str = dataset_argument(),
    output: Path = output_folder_option(),
    source: LandmarkSource = landmark_source_options(
        "Ignore the dataset's landmark ids: per-particle maximum-likelihood association "
        "(Table 13.2; Victoria Park has no ids and always runs so)."
    ),
    particles: int | None = opt.particles_option("Particles [default: 100]."),
    version: int | None = typer.Option(
        None, "--version", help="FastSLAM 1 or 2 (Tables 13.1, 13.3) [default: 2]."
    ),
    seed: int | None = opt.seed_option(),
    p0: float | None = typer.Option(
        None,
        "--p0",
        help="New-landmark likelihood p0 for unknown ids (1/(m rad)) [default: 0.001].",
    ),
    config: Path | None = estimator_config_option(
        "FastSLAMConfig", "; the options given here override it."
    ),
    report: dict[str, Any] = report_options(),
) -> None:
    """FastSLAM 1.0 / 2.0 (Probabilistic Robotics ch. 13), known or unknown landmark ids:
    writes trajectory.csv (weighted mean pose), landmarks.csv (heaviest particle), metrics.json
    and slam.png (and trajectory.tum with --tum) into OUTPUT, like 'probmap slam ekf'."""
    watch = Stopwatch()
    with cli_errors():
        from probmap.cli.common import resolve_config
        from probmap.slam.landmark.fastslam import FastSLAM, FastSLAMConfig

        overrides = {
            "n_particles": particles,
            "version": version,
            "seed": seed,
            "new_landmark_likelihood": p0,
        }
        cfg = resolve_config(FastSLAMConfig, config, overrides)
        ds = read_landmark_dataset(watch, output, dataset, source)
        if config is None:  # a file gives every field; without one, the dataset's defaults
            from probmap.pipelines.landmark_slam import default_fastslam_config

            cfg = default_fastslam_config(ds, cfg)
        slam = FastSLAM(ds.motion_model, ds.measurement_model, ds.initial_pose, cfg)
        title = f"FastSLAM {cfg.version}.0 ({cfg.n_particles} particles)"
        run_and_report(slam, ds, output, title, watch=watch, **report)


def register(app: typer.Typer) -> None:
    """Mount ``probmap slam`` (``probmap datasets`` is in :mod:`probmap.cli.datasets`)."""
    app.add_typer(slam_app, name="slam")
