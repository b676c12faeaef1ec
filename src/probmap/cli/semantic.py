"""``probmap semantic``: multi-class (semantic) occupancy grid mapping from labelled scans."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from probmap.cli import options as opt
from probmap.cli.common import cli_errors, input_rows, print_summary


def _demo_time_row(summary: dict[str, Any], watch: Any = None) -> tuple[str, str]:
    """The demo's time row, as :meth:`probmap.cli.common.Stopwatch.row` writes it: the total
    (the command's stopwatch when given, else the sum of the phases) and its phases."""
    phases = {k: float(summary[f"{k} seconds"]) for k in ("simulate", "map", "write")}
    total = watch.total if watch is not None else sum(phases.values())
    parts = ", ".join(f"{k} {v:.1f} s" for k, v in phases.items())
    return ("time", f"{total:.1f} s ({parts})")


def print_semantic_demo(summary: dict[str, Any], watch: Any = None) -> None:
    """Print what :func:`probmap.pipelines.semantic.run_semantic_demo` returned (for ``demo``);
    ``watch``, the command's :class:`~probmap.cli.common.Stopwatch`, gives the total time."""
    from rich.console import Console
    from rich.table import Table

    rows = [
        ("scans", f"{summary['scans']:,}"),
        ("beams", f"{summary['beams']:,} ({summary['hits']:,} hits)"),
        ("wrong labels", str(summary["wrong labels"])),
        ("cells updated", f"{summary['cell updates']:,}"),
        ("observed cells", f"{summary['observed cells']:,}"),
        ("calibration error", f"{summary['calibration error']:.3f} (ECE, 10 bins)"),
        _demo_time_row(summary, watch),
    ]
    rows += [("wrote", f) for f in summary["files"]]
    print_summary("probmap demo --semantic: labelled floor plan", rows)
    iou = Table(title="per-class IoU on observed cells")
    iou.add_column("class")
    iou.add_column("IoU (1-cell tolerance)", justify="right")
    iou.add_column("IoU (strict)", justify="right")
    for name, v in summary["iou"].items():
        iou.add_row(name, f"{v:.4f}", f"{summary['iou strict'][name]:.4f}")
    Console().print(iou)


def semantic_command(
    scans: Path = typer.Argument(..., help="Labelled scans (.npz: poses, ranges, angles, ...)."),
    output: str = opt.output_option(
        "Output prefix: PREFIX.{npz,png}, PREFIX.occupancy.{yaml,pgm,npz,png} and "
        "PREFIX.config.yaml; an "
        "existing folder (or a name ending in /) writes FOLDER/semantic.*. Missing folders are "
        "created."
    ),
    resolution: float | None = opt.resolution_option(),
    p_hit: float | None = opt.p_hit_option("p(not free) at a beam's endpoint [default: 0.7]."),
    p_miss: float | None = opt.p_miss_option("p(not free) along a beam [default: 0.4]."),
    p_correct: float | None = typer.Option(
        None,
        "--p-correct",
        help="Probability that a hard label is right (confusion model) [default: 0.9].",
    ),
    max_clear: float | None = opt.max_clear_option(
        "Free space cleared by max-range readings, metres [default: the max range]."
    ),
    config: Path | None = opt.config_option(
        "A YAML file of SemanticMappingConfig fields (as PREFIX.config.yaml records it); "
        "the options given here override it."
    ),
    chunk: int = typer.Option(500, "--chunk", help="Scans per kernel call (progress steps)."),
) -> None:
    """Build a semantic map from labelled scans and write it with its occupancy grid and
    PREFIX.config.yaml (the settings used, the command line and the probmap version)."""
    with cli_errors():
        import dataclasses

        from probmap._atomic import atomic_outputs
        from probmap.cli._provenance import write_run_config
        from probmap.cli.common import Stopwatch, progress_bar, resolve_config
        from probmap.datasets.validate import require_usable, validate_ranges
        from probmap.grid.semantic_io import read_labelled_scans, write_semantic_maps
        from probmap.pipelines import check_output_prefix
        from probmap.pipelines.semantic import SemanticMappingConfig

        watch = Stopwatch()
        if not scans.exists():
            raise FileNotFoundError(f"{scans}: no such file")
        if chunk < 1:
            raise ValueError(f"--chunk must be >= 1, got {chunk}")
        overrides = {
            "resolution": resolution,
            "p_hit": p_hit,
            "p_miss": p_miss,
            "p_correct": p_correct,
            "max_clear": max_clear,
        }
        cfg = resolve_config(SemanticMappingConfig, config, overrides)
        prefix = check_output_prefix(output, "semantic")
        with watch("read"):
            data = read_labelled_scans(scans)
            # the one reading rule of every command: zero and invalid readings dropped, +inf
            # no return
            cleaned, readings = validate_ranges(data.ranges, data.max_range)
            require_usable(readings, scans, data.max_range)
            if cleaned is not data.ranges:
                import numpy as np

                data = dataclasses.replace(data, ranges=np.asarray(cleaned, dtype=np.float64))
        with watch("compute"):
            grid = data.make_grid(resolution=cfg.resolution, model=cfg.model())
            stats = None
            with progress_bar(f"mapping {scans.name}", unit="scans") as bar:
                task = bar.add_task(scans.name, total=len(data))
                for start in range(0, len(data), chunk):
                    s = data.integrate_into(grid, start, start + chunk)
                    stats = s if stats is None else stats + s
                    bar.update(task, completed=min(start + chunk, len(data)))
        with watch("write"), atomic_outputs():  # the seven files or none
            files = write_semantic_maps(prefix, grid)
            from probmap.viz.maps import save_map_figure

            files.append(
                save_map_figure(
                    f"{prefix}.occupancy.plot.png", grid.to_occupancy(),
                    trajectory=data.poses, title=scans.name,
                )
            )  # fmt: skip
            files.append(write_run_config(f"{prefix}.config.yaml", cfg))
        cls = grid.classify()
        rows = [("scans", f"{len(data):,}")]
        if stats is not None:
            rows += [
                (
                    "beams",
                    f"{stats.beams:,} ({stats.hits:,} hits, {stats.max_range:,} max-range, "
                    f"{stats.dropped:,} dropped)",
                ),
                *input_rows(readings),
                ("cells updated", f"{stats.cell_updates:,}"),
            ]
        spec = grid.spec
        rows.append(("map size", f"{spec.width} x {spec.height} cells at {spec.resolution:g} m"))
        rows.append(("observed cells", f"{int((cls >= 0).sum()):,}"))
        for k, name in enumerate(grid.classes):
            rows.append((f"  {name}", f"{int((cls == k).sum()):,} cells"))
        rows.append(watch.row())
        rows += [("wrote", str(f)) for f in files]
        print_summary(f"probmap semantic {scans.name}", rows)


def register(app: typer.Typer) -> None:
    """Attach the semantic mapping command."""
    app.command("semantic", short_help="Semantic map from labelled scans.")(semantic_command)
