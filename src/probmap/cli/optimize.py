"""``probmap optimize``: optimize a 2-D pose graph (g2o or TORO) and write it as g2o."""

from __future__ import annotations

from pathlib import Path

import typer

from probmap.cli.common import cli_errors

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
    output: str = typer.Option(
        ...,
        "-o",
        "--output",
        help="Optimized graph (g2o); an existing folder (or a name ending in /) gets "
        "FOLDER/optimized.g2o. Missing folders are created.",
    ),
    robust: str = typer.Option("none", "--robust", help=ROBUST_HELP),
    robust_scale: float | None = typer.Option(None, "--robust-scale", help=SCALE_HELP),
    max_iterations: int = typer.Option(
        100, "--max-iterations", help="Most Levenberg-Marquardt iterations."
    ),
    robust_edges: str = typer.Option(
        "all",
        "--robust-edges",
        help="Edges under the kernel: all, or closures (every edge but i -> i+1 odometry).",
    ),
    init: str = typer.Option("auto", "--init", help=INIT_HELP),
) -> None:
    """Levenberg-Marquardt on GRAPH; writes the optimized graph and prints the errors
    (GTSAM's convention: 0.5 * sum e' Omega e, the first pose held fixed)."""
    with cli_errors():
        import numpy as np
        from rich.console import Console
        from rich.table import Table

        from probmap._atomic import atomic_outputs
        from probmap.datasets.g2o import pose_graph_arrays, read_pose_graph, with_poses, write_g2o
        from probmap.pipelines import check_output_prefix
        from probmap.slam.posegraph import OptimizerConfig, optimize_pose_graph

        target = check_output_prefix(output, "optimized.g2o")
        if init not in ("auto", "given", "lago"):
            raise ValueError(f"--init must be auto, given or lago, got {init!r}")
        if robust not in ("none", "huber", "cauchy", "dcs"):
            raise ValueError(f"--robust must be none, huber, cauchy or dcs, got {robust!r}")
        if init == "auto":
            init = "lago" if robust == "none" else "given"
        if robust_edges not in ("all", "closures"):
            raise ValueError(f"--robust-edges must be 'all' or 'closures', got {robust_edges!r}")
        config = OptimizerConfig(
            max_iterations=max_iterations,
            robust=robust,  # type: ignore[arg-type]  # validated by OptimizerConfig
            robust_scale=robust_scale,
        )
        g = read_pose_graph(graph)
        a = pose_graph_arrays(g)
        fixed = a.fixed if a.fixed.size else (0,)
        ids = a.ids[a.edges]
        mask = None if robust_edges == "all" else np.abs(ids[:, 1] - ids[:, 0]) != 1
        try:
            r = optimize_pose_graph(
                a.poses,
                a.edges,
                a.measurements,
                a.information,
                config,
                fixed=fixed,
                robust_mask=mask,
                init=init,  # type: ignore[arg-type]  # checked above
            )
        except ValueError as exc:
            raise ValueError(f"{graph}: {exc}") from None
        with atomic_outputs():  # a missing folder is created
            write_g2o(target, with_poses(g, a.ids, r.poses))

        table = Table(title=f"pose-graph optimization of {graph.name}")
        table.add_column("")
        table.add_column("value", justify="right")
        table.add_row("format", g.format + (" (poses chained from odometry)" if g.chained else ""))
        table.add_row("nodes", f"{len(a.ids):,}")
        table.add_row("edges", f"{len(a.edges):,}")
        if g.equivalences:
            table.add_row("EQUIV lines (not merged)", f"{len(g.equivalences):,}")
        table.add_row("fixed nodes", ", ".join(str(int(a.ids[i])) for i in fixed))
        kernel = f"{config.robust} (scale {config.scale:g}, {robust_edges} edges)"
        table.add_row("robust kernel", kernel if config.robust != "none" else "none")
        table.add_row("start", "LAGO estimate" if init == "lago" else "poses in the file")
        table.add_row("initial error", f"{r.initial_error:.6g}")
        table.add_row("final error", f"{r.final_error:.6g}")
        table.add_row("iterations", str(r.iterations))
        table.add_row("converged", f"{'yes' if r.converged else 'no'}: {r.message}")
        table.add_row("time", f"{r.seconds:.3f} s")
        if config.robust != "none":
            table.add_row("edges with weight < 0.5", f"{int((r.weights < 0.5).sum()):,}")
        console = Console()
        console.print(table)
        console.print(f"wrote {target}")


def register(app: typer.Typer) -> None:
    """Attach ``probmap optimize``."""
    app.command("optimize")(optimize_command)
