"""``probmap slam seif`` and ``probmap slam compare`` (SEIF SLAM, and SEIF beside EKF)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import typer

from probmap.cli import options as opt
from probmap.cli.common import cli_errors
from probmap.cli.landmark_slam import (
    LandmarkSource,
    dataset_argument,
    landmark_source_options,
    limit_threads,
    output_folder_option,
    read_landmark_dataset,
    report_options,
    slam_app,
    threads_option,
)

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


@slam_app.command("seif")
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


@slam_app.command("compare")
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
    """The commands attach to ``slam_app`` when this module is imported; nothing else to do."""
    del app
