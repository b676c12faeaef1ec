"""``probmap slam ekf|seif|graphslam|fastslam|compare`` (landmark SLAM) and the ``probmap slam``
group itself (``slam grid``, laser SLAM, is added by :mod:`probmap.cli.laser_slam`).

The helpers :func:`read_landmark_dataset`, :func:`limit_threads`, :func:`run_and_report` and the
option factories are shared by the five landmark commands.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
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
    help="Simultaneous localization and mapping, of two kinds.\n\n"
    "Grid SLAM (grid) builds an occupancy grid map and the trajectory from a raw laser log or "
    "ROS bag: graph SLAM with submaps and loop closure (default) or a Rao-Blackwellized "
    "particle filter (--method rbpf).\n\n"
    "Landmark SLAM (ekf, seif, graphslam, fastslam, compare) estimates landmark positions and "
    "the trajectory from a landmark dataset (UTIAS MRCLAM, Victoria Park; probmap datasets "
    "list).",
    short_help="Grid SLAM of laser logs and bags; landmark SLAM.",
    no_args_is_help=True,
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
    asked = stop is not None and stop()  # a Ctrl-C during the last step ends no earlier
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
    if result.interrupted or asked:
        done = len(result.trajectory)
        rows.insert(0, ("interrupted", f"at step {done:,} of {result.steps_total:,}"))
    print_summary(f"{title} on {metrics['dataset']}", rows)
    if result.interrupted or asked:
        interrupted_exit(len(result.trajectory), result.steps_total, "steps", wrote=True)
    return metrics


@slam_app.command("ekf", short_help="EKF SLAM of a landmark dataset (Table 10.1/10.2).")
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


@slam_app.command(
    "graphslam", short_help="GraphSLAM of a whole landmark dataset (Tables 11.1-11.5)."
)
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


@slam_app.command("fastslam", short_help="FastSLAM 1.0 or 2.0 of a landmark dataset.")
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


# ----------------------------------------------------------------- SEIF and the comparison
MAX_ACTIVE_HELP = "Bound on the active landmarks (Table 12.4); 0 = unbounded (no sparsification)."
CONTEXT_HELP = (
    "Sparsify marginalising the passive landmarks within this many links of the active set "
    "instead of conditioning on them (0 = Table 12.4 as printed; 1 removes most of its "
    "overconfidence)."
)


# the two SEIF options of 'slam seif' and 'slam compare' (one definition each)
def max_active_option() -> Any:
    return typer.Option(None, "--max-active", help=MAX_ACTIVE_HELP + " [default: 10]")


def context_hops_option() -> Any:
    return typer.Option(None, "--context-hops", help=CONTEXT_HELP + " [default: 0]")


CONFIG_HELP = (
    "A YAML file of SeifConfig fields (as 'slam seif' records it in OUTPUT/config.yaml); "
    "--max-active and --context-hops override it."
)


def _seif_config(file_cfg: Any, max_active: int | None, context_hops: int | None) -> Any:
    """SEIF's configuration: ``file_cfg`` (the SeifConfig of ``--config``, or of the ``seif``
    section of ``slam compare``'s file; the class defaults when None), then the options given
    (``--max-active 0``: unbounded)."""
    import dataclasses

    from probmap.slam.landmark.seif import SeifConfig

    if max_active is not None and max_active < 0:
        raise ValueError(f"--max-active must be >= 0, got {max_active}")
    if context_hops is not None and context_hops < 0:
        raise ValueError(f"--context-hops must be >= 0, got {context_hops}")
    cfg = file_cfg if file_cfg is not None else SeifConfig()
    if max_active is not None:
        cfg = dataclasses.replace(cfg, max_active=max_active or None)
    if context_hops is not None:
        cfg = dataclasses.replace(cfg, context_hops=context_hops)
    return cfg


COMPARED = ("ekf", "seif", "graphslam", "fastslam")


def _sections(config: Path | None) -> dict[str, str] | None:
    """``slam compare --config``: ``{method: YAML text of its section}`` when the file's top
    level holds only method names (``ekf:``, ``seif:``, ``graphslam:``, ``fastslam:``); None
    when it is a plain SeifConfig file (or there is no file)."""
    if config is None:
        return None
    import yaml

    try:
        data = yaml.safe_load(Path(config).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return None  # load_config reports it, naming the file
    if not (isinstance(data, dict) and data and set(data) <= set(COMPARED)):
        return None
    return {k: yaml.safe_dump(v if v is not None else {}) for k, v in data.items()}


def _method_config(
    cls: type,
    sections: dict[str, str],
    method: str,
    config: Path | None,
    default: Callable[[], Any],
) -> Any:
    """``method``'s configuration in ``slam compare``: its section of the file ``config`` when
    there is one, else ``default()`` (the dataset's settings)."""
    if method not in sections:
        return default()
    from probmap.config import load_config

    return load_config(cls, sections[method], source=f"{config}: {method}")


def _seif(ds: Any, cfg: Any) -> Any:
    from probmap.slam.landmark.seif import build_seif

    return build_seif(ds, cfg)


def _label(cfg: Any) -> str:
    text = f"max_active={cfg.max_active or 'unbounded'}"
    return text + (f", context_hops={cfg.context_hops}" if cfg.context_hops else "")


@slam_app.command("seif", short_help="SEIF SLAM of a landmark dataset (Tables 12.1-12.5).")
@opt.with_option_groups
def seif_command(
    dataset: str = dataset_argument(),
    output: Path = output_folder_option(),
    max_active: int | None = max_active_option(),
    context_hops: int | None = context_hops_option(),
    config: Path | None = opt.config_option(CONFIG_HELP),
    source: LandmarkSource = landmark_source_options(),
    threads: int = threads_option(),
    report: dict[str, Any] = report_options(),
) -> None:
    """SEIF SLAM (Probabilistic Robotics Tables 12.1-12.5): writes trajectory.csv,
    landmarks.csv, metrics.json, config.yaml and slam.png (and trajectory.tum with --tum) into
    OUTPUT, like 'probmap slam ekf'."""
    from probmap.cli.common import Stopwatch

    watch = Stopwatch()  # the summary time covers the whole command
    limit_threads(threads)
    with cli_errors():
        from probmap.cli.landmark_slam import run_and_report
        from probmap.config import load_config
        from probmap.slam.landmark.seif import SeifConfig

        file_cfg = None if config is None else load_config(SeifConfig, config)
        cfg = _seif_config(file_cfg, max_active, context_hops)
        ds = read_landmark_dataset(watch, output, dataset, source)
        title = f"SEIF SLAM ({_label(cfg)})"
        run_and_report(_seif(ds, cfg), ds, output, title, watch=watch, **report)


def _state_bytes(estimator: Any) -> int:
    if hasattr(estimator, "state_nbytes"):
        return int(estimator.state_nbytes())
    d = 3 + 2 * int(estimator.n_landmarks)  # dense EKF: covariance and mean
    return 8 * (d * d + d)


@slam_app.command(
    "compare", short_help="Run several landmark-SLAM methods on a dataset and compare."
)
@opt.with_option_groups
def compare_command(
    dataset: str = dataset_argument(),
    max_active: int | None = max_active_option(),
    context_hops: int | None = context_hops_option(),
    config: Path | None = opt.config_option(
        "A YAML file with one section per method (ekf: EKFConfig, seif: SeifConfig, "
        "graphslam: GraphSLAMConfig, fastslam: FastSLAMConfig fields; a section replaces that "
        "method's dataset defaults), or SEIF's SeifConfig fields alone; --max-active and "
        "--context-hops override SEIF's."
    ),
    source: LandmarkSource = landmark_source_options(),
    threads: int = threads_option(),
    methods: str = typer.Option(
        "ekf,seif", "--methods", help="Comma-separated estimators: ekf, seif, graphslam, fastslam."
    ),
) -> None:
    """Run EKF and SEIF (or the --methods given, GraphSLAM included) on the same data in one
    process and print one table: time per step, state memory, robot and landmark RMSE, pose
    ANEES. Writes no file."""
    from probmap.cli.common import Stopwatch

    watch = Stopwatch()  # the summary time covers the whole command
    limit_threads(threads)
    with cli_errors():
        from rich.console import Console
        from rich.table import Table

        from probmap.cli.common import progress_bar
        from probmap.config import load_config
        from probmap.pipelines.landmark_slam import default_ekf_config, evaluate, run_landmark_slam
        from probmap.slam.landmark.ekf import build_ekf
        from probmap.slam.landmark.seif import SeifConfig

        chosen = [m.strip().lower() for m in methods.split(",") if m.strip()]
        if not chosen or any(m not in COMPARED for m in chosen):
            raise ValueError(f"--methods takes a list of {', '.join(COMPARED)}, got {methods!r}")
        sections = _sections(config)
        own = sections or {}
        if sections is None:  # a plain SeifConfig file, or none
            seif_file = None if config is None else load_config(SeifConfig, config)
        else:  # its seif section, or SEIF's defaults
            seif_file = _method_config(SeifConfig, own, "seif", config, SeifConfig)
        seif_cfg = _seif_config(seif_file, max_active, context_hops)
        ds = read_landmark_dataset(watch, None, dataset, source)
        runs = []
        seif_name = f"SEIF-{seif_cfg.max_active or 'unbounded'}" + (
            f"-ctx{seif_cfg.context_hops}" if seif_cfg.context_hops else ""
        )
        estimators: list[tuple[str, Any]] = []
        for method in dict.fromkeys(chosen):
            if method == "ekf":
                from probmap.slam.landmark.ekf import EKFConfig

                ekf_cfg = _method_config(
                    EKFConfig, own, "ekf", config, lambda: default_ekf_config(ds)
                )
                estimators.append(("EKF", build_ekf(ds, ekf_cfg)))
            elif method == "seif":
                estimators.append((seif_name, _seif(ds, seif_cfg)))
            elif method == "fastslam":
                from probmap.pipelines.landmark_slam import default_fastslam_config
                from probmap.slam.landmark.fastslam import FastSLAM, FastSLAMConfig

                fs_cfg = _method_config(
                    FastSLAMConfig, own, "fastslam", config, lambda: default_fastslam_config(ds)
                )
                fs = FastSLAM(ds.motion_model, ds.measurement_model, ds.initial_pose, fs_cfg)
                estimators.append((f"FastSLAM-{fs_cfg.version}.0", fs))
            else:
                from probmap.pipelines.landmark_slam import default_graphslam_config
                from probmap.slam.landmark.graphslam import GraphSLAMConfig, build_graphslam

                gs_cfg = _method_config(
                    GraphSLAMConfig, own, "graphslam", config, lambda: default_graphslam_config(ds)
                )
                estimators.append(("GraphSLAM", build_graphslam(ds, gs_cfg)))
        for k, (name, est) in enumerate(estimators, start=1):
            label = f"{name} ({k}/{len(estimators)})"
            with watch("compute"):
                with progress_bar(label, unit="steps") as bar:
                    task = bar.add_task(label, total=len(ds))

                    def tick(i: int, n: int, b: Any = bar, t: Any = task) -> None:
                        b.update(t, completed=i)

                    result = run_landmark_slam(est, ds, progress=tick)
                metrics = evaluate(result, ds, with_dead_reckoning=False)
            runs.append((name, metrics, est, result))
        names = " vs ".join(name.split("-")[0] for name, _ in estimators)
        table = Table(title=f"{names} on {getattr(ds, 'name', dataset)}")

        def get(m: dict[str, Any], *keys: str) -> str:
            v: Any = m
            for k in keys:
                if not isinstance(v, dict) or k not in v:
                    return "-"
                v = v[k]
            return f"{v:.3f}"

        # (header, metrics keys, what the footnote says of it); only columns some run fills
        columns: list[tuple[str, tuple[str, ...], str]] = [
            ("robot", ("ate", "translation_m", "rmse"), "robot position RMSE, map frame"),
            ("robot al", ("ate_aligned", "translation_m", "rmse"),
             "the same after the SE(2) fit of the trajectory onto the reference"),
            ("lm", ("landmarks", "error_m", "rmse"), "landmark RMSE, map frame"),
            ("lm al", ("landmarks_aligned", "error_m", "rmse"),
             "the same after the SE(2) fit of the landmarks onto the truth"),
            ("GPS al", ("gps", "rmse_m"),
             "RMSE against GPS after the SE(2) fit of the trajectory onto the fixes"),
            ("ANEES", ("pose_nees", "mean"),
             "pose ANEES, the mean NEES over the steps: 3 (the pose's dof) when consistent, "
             "larger = overconfident"),
        ]  # fmt: skip
        columns = [c for c in columns if any(get(m, *c[1]) != "-" for _, m, _, _ in runs)]
        table.add_column("estimator", no_wrap=True)
        for col in ["ms/step", "median", "MiB", "map"] + [c[0] for c in columns]:
            table.add_column(col, justify="right")
        for name, m, est, _ in runs:
            table.add_row(
                name,
                f"{m['step_ms']['mean']:.3f}",
                f"{m['step_ms']['median']:.3f}",
                f"{_state_bytes(est) / 2**20:.3f}",
                f"{m['landmarks_mapped']:,}",
                *[get(m, *c[1]) for c in columns],
            )
        console = Console()
        if not console.is_terminal:  # piped: no terminal width to respect, never cut a figure
            console = Console(width=160)
        console.print(table)
        notes = [
            "ms/step: mean wall time of predict + update; median: its median",
            "MiB: the estimator's state (mean and covariance or information)",
            "map: landmarks mapped",
            *(f"{c[0]}: {c[2]}" for c in columns if c[0] != "ANEES"),
            *(c[2] for c in columns if c[0] == "ANEES"),
        ]
        peak = max(r.peak_rss_bytes for _, _, _, r in runs)
        notes.append(f"errors in metres; process peak RSS {peak / 2**20:.1f} MiB (all runs)")
        Console().print(".\n".join(notes) + ".")
        name, value = watch.row()
        Console().print(f"{name} {value}")


def register(app: typer.Typer) -> None:
    """Mount ``probmap slam`` (``probmap datasets`` is in :mod:`probmap.cli.datasets`)."""
    app.add_typer(slam_app, name="slam")
