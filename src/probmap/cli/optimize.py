"""``probmap optimize``: optimize a 2-D pose graph (g2o or TORO) and write it as g2o."""

from __future__ import annotations

from pathlib import Path

import typer

from probmap.cli import options as opt
from probmap.cli.common import check_choice, cli_errors

ROBUST_HELP = (
    "Robust kernel for every edge: none, huber, cauchy or dcs (dynamic covariance scaling)."
)
SCALE_HELP = (
    "Kernel scale: Huber/Cauchy k in Mahalanobis-distance units, DCS Phi in chi2 units "
    "(default: huber 1.345, cauchy 2.3849, dcs 1)."
)
INIT_HELP = (
    "Start from the file's poses (given) or from the linear LAGO estimate (lago: headings, then "
    "positions, by linear least squares; best for graphs whose headings are far off, but not "
    "robust to false edges). auto: lago without a robust kernel, given with one."
)


def optimize_command(
    graph: Path = typer.Argument(..., help="Pose graph: g2o (VERTEX_SE2/EDGE_SE2) or TORO."),
    output: str = opt.output_option(
        "Optimized graph (g2o); an existing folder (or a name ending in /) gets "
        "FOLDER/optimized.g2o. Missing folders are created."
    ),
    robust: str | None = typer.Option(None, "--robust", help=ROBUST_HELP + " [default: none]"),
    robust_scale: float | None = typer.Option(None, "--robust-scale", help=SCALE_HELP),
    max_iterations: int | None = typer.Option(
        None, "--max-iterations", help="Most Levenberg-Marquardt iterations [default: 100]."
    ),
    robust_edges: str | None = typer.Option(
        None,
        "--robust-edges",
        help="Edges under the kernel: all, or closures (every edge but i -> i+1 odometry) "
        "[default: all].",
    ),
    init: str | None = typer.Option(None, "--init", help=INIT_HELP + " [default: auto]"),
    edge2_order: str = typer.Option(
        "auto",
        "--edge2-order",
        help="Order of the information values on TORO EDGE2 lines: toro (I11 I12 I22 I33 I13 "
        "I23), g2o (I11 I12 I13 I22 I23 I33, as GTSAM's w20000.txt writes them) or auto "
        "(the one that makes every matrix positive semi-definite, TORO's first).",
    ),
    config: Path | None = opt.config_option(
        "A YAML file of PoseGraphConfig fields (iterations, tolerances, damping, robust "
        "kernel and scale, chart, robust_edges, init), as PREFIX.config.yaml records it; the "
        "options given here override it."
    ),
    plot: bool = typer.Option(
        True,
        "--plot/--no-plot",
        help="Also write PREFIX.plot.png: the graph before (the file's poses) and after the "
        "optimization, side by side.",
    ),
) -> None:
    """Levenberg-Marquardt on GRAPH; writes the optimized graph, beside it the settings used
    (PREFIX.config.yaml: with the command line and the probmap version) and a before-and-after
    picture (PREFIX.plot.png: the odometry chain over a light layer of loop closures), and
    prints the errors (GTSAM's convention: 0.5 * sum e' Omega e, the first pose held
    fixed)."""
    with cli_errors():
        from rich.console import Console
        from rich.table import Table

        from probmap._atomic import atomic_outputs
        from probmap.cli._provenance import write_run_config
        from probmap.cli.common import Stopwatch, resolve_config
        from probmap.datasets.g2o import read_pose_graph, with_poses, write_g2o
        from probmap.pipelines import check_output_prefix
        from probmap.pipelines.optimize import PoseGraphConfig, optimize_graph

        watch = Stopwatch()
        target = check_output_prefix(output, "optimized.g2o")
        stem = target.name[: -len(".g2o")] if target.name.endswith(".g2o") else target.name
        config_path = target.with_name(f"{stem}.config.yaml")
        plot_path = target.with_name(f"{stem}.plot.png")
        check_choice("--init", init, ("auto", "given", "lago"))
        check_choice("--robust", robust, ("none", "huber", "cauchy", "dcs"))
        check_choice("--robust-edges", robust_edges, ("all", "closures"))
        check_choice("--edge2-order", edge2_order, ("auto", "toro", "g2o"))
        overrides = {
            "robust": robust,
            "robust_scale": robust_scale,
            "max_iterations": max_iterations,
            "robust_edges": robust_edges,
            "init": init,
        }
        cfg = resolve_config(PoseGraphConfig, config, overrides)
        with watch("read"):
            g = read_pose_graph(graph, edge2_order=edge2_order)  # type: ignore[arg-type]
        with watch("compute"):
            try:
                run = optimize_graph(g, cfg)
            except ValueError as exc:
                raise ValueError(f"{graph}: {exc}") from None
        a, r, opt = run.arrays, run.result, cfg.optimizer()
        with watch("write"), atomic_outputs():  # every file or none; a missing folder is made
            write_g2o(target, with_poses(g, a.ids, r.poses))
            write_run_config(config_path, cfg)
            if plot:
                from probmap.viz.laser_slam import save_pose_graph_figure

                save_pose_graph_figure(
                    plot_path, a.ids, a.edges, a.poses, r.poses, title=graph.name,
                    before_label=f"before: the file's poses (error {r.initial_error:.6g})",
                    after_label=(
                        f"after: {r.iterations} iterations (error {r.final_error:.6g})"
                    ),
                    weights=r.weights if opt.robust != "none" else None,
                )  # fmt: skip

        table = Table(title=f"pose-graph optimization of {graph.name}")
        table.add_column("")
        table.add_column("value", justify="right")
        table.add_row("format", g.format + (" (poses chained from odometry)" if g.chained else ""))
        table.add_row("nodes", f"{len(a.ids):,}")
        table.add_row("edges", f"{len(a.edges):,}")
        if g.edge2_order is not None:
            how = "detected" if edge2_order == "auto" else "--edge2-order"
            table.add_row("EDGE2 information order", f"{g.edge2_order} ({how})")
        if g.equivalences:
            table.add_row("EQUIV lines (not merged)", f"{len(g.equivalences):,}")
        table.add_row("fixed nodes", ", ".join(str(int(a.ids[i])) for i in run.fixed))
        kernel = f"{opt.robust} (scale {opt.scale:g}, {cfg.robust_edges} edges)"
        table.add_row("robust kernel", kernel if opt.robust != "none" else "none")
        table.add_row("start", "LAGO estimate" if cfg.start == "lago" else "poses in the file")
        table.add_row("initial error", f"{r.initial_error:.6g}")
        table.add_row("final error", f"{r.final_error:.6g}")
        table.add_row("iterations", str(r.iterations))
        table.add_row("converged", f"{'yes' if r.converged else 'no'}: {r.message}")
        if opt.robust != "none":
            table.add_row("edges with weight < 0.5", f"{int((r.weights < 0.5).sum()):,}")
        table.add_row(*watch.row())
        console = Console()
        console.print(table)
        console.print(f"wrote {target}")
        console.print(f"wrote {config_path}")
        if plot:
            console.print(f"wrote {plot_path}")
        if not r.converged:
            typer.echo(f"warning: {graph}: not converged: {r.message}", err=True)


def register(app: typer.Typer) -> None:
    """Attach ``probmap optimize``."""
    app.command("optimize", short_help="Optimize a pose graph (g2o) by Levenberg-Marquardt.")(
        optimize_command
    )
