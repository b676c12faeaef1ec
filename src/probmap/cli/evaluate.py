"""``probmap evaluate relations``: the relation-based SLAM metric of Kuemmerle et al. (2009)."""

from __future__ import annotations

from pathlib import Path

import typer

from probmap.cli import options as opt
from probmap.cli.common import cli_errors

evaluate_app = typer.Typer(
    help="Score trajectories and maps against references.", no_args_is_help=True
)


@evaluate_app.command(
    "relations", short_help="Relation error of a trajectory against a .relations file."
)
def relations_command(
    trajectory: Path = typer.Argument(..., help="Trajectory CSV (time,x,y,theta) or a CARMEN log."),
    relations: Path = typer.Argument(
        ..., help="Relations file (t1 t2 dx dy dz droll dpitch dyaw)."
    ),
    tolerance: float | None = typer.Option(
        None, "--tolerance", help="Timestamp matching tolerance, seconds [default: 0.001]."
    ),
    poses: str | None = opt.poses_option(
        "For a CARMEN log: robot (odom fields) or laser poses [default: robot]."
    ),
    config: Path | None = opt.config_option(
        "A YAML file of RelationsConfig fields (tolerance, poses); the options given here "
        "override it."
    ),
    output: str | None = opt.output_option(
        "Also write the figures as JSON, with the settings used ('configuration'), the "
        "command line and the probmap version; an existing folder (or a name ending in /) gets "
        "FOLDER/relations.json. Missing folders are created.",
        default=None,
    ),
) -> None:
    """Relation error of a trajectory: mean and std of translational and rotational errors."""
    from probmap.cli.common import Stopwatch

    watch = Stopwatch()  # the time line covers the whole command
    with cli_errors():
        import json

        import yaml
        from rich.console import Console
        from rich.table import Table

        from probmap._atomic import atomic_outputs, atomic_write
        from probmap.cli._provenance import command_line
        from probmap.cli.common import resolve_config
        from probmap.config import dump_config, package_version
        from probmap.metrics.relations import (
            RelationsConfig,
            read_relations,
            read_trajectory,
            relation_errors,
        )
        from probmap.pipelines import check_output_prefix

        target = None if output is None else check_output_prefix(output, "relations.json")
        cfg = resolve_config(RelationsConfig, config, {"tolerance": tolerance, "poses": poses})
        with watch("read"):
            times, xy = read_trajectory(trajectory, poses=cfg.poses)
            rel = read_relations(relations)
        with watch("compute"):
            s = relation_errors(times, xy, rel, tolerance=cfg.tolerance).summary()
        if target is not None:  # written before anything is printed: an error is one line
            doc = {
                **s,
                "probmap_version": package_version(),
                "command": command_line(),
                "configuration": yaml.safe_load(dump_config(cfg)),
            }
            with watch("write"), atomic_outputs(), atomic_write(target, "w") as f:
                json.dump(doc, f, indent=2)
        table = Table(title=f"relation error of {trajectory.name} on {relations.name}")
        table.add_column("error")
        table.add_column("absolute: mean ± std", justify="right")
        table.add_column("squared: mean ± std", justify="right")
        table.add_row(
            "translation",
            f"{s['trans_abs_mean_m']:.3f} ± {s['trans_abs_std_m']:.3f} m",
            f"{s['trans_sq_mean_m2']:.3f} ± {s['trans_sq_std_m2']:.3f} m²",
        )
        table.add_row(
            "rotation",
            f"{s['rot_abs_mean_deg']:.2f} ± {s['rot_abs_std_deg']:.2f} deg",
            f"{s['rot_sq_mean_deg2']:.1f} ± {s['rot_sq_std_deg2']:.1f} deg²",
        )
        console = Console()
        console.print(table)
        console.print(
            f"{int(s['relations'])} relations evaluated, {int(s['missing'])} without poses"
        )
        name, value = watch.row()
        console.print(f"{name} {value}")
        if target is not None:
            console.print(f"wrote {target}")


def register(app: typer.Typer) -> None:
    """Attach ``probmap evaluate``."""
    app.add_typer(evaluate_app, name="evaluate")
