"""``probmap info BAG``: topics, message types, counts, frames and durations of a ROS bag."""

from __future__ import annotations

import math
from pathlib import Path

import typer

from probmap.cli import options as opt
from probmap.cli.common import cli_errors, laser_input, print_summary


def _seconds(t: float) -> str:
    return "-" if math.isnan(t) else f"{t:.3f}"


def info_command(
    bag: Path = typer.Argument(
        ...,
        help="A ROS 1 .bag file, or a ROS 2 bag folder (.db3 or .mcap storage), or a dataset "
        "name (intel-bag).",
    ),
    data_dir: Path | None = opt.data_dir_option(),
) -> None:
    """List a ROS bag's topics, message types, counts, frames and time spans."""
    with cli_errors():
        from rich.console import Console
        from rich.table import Table

        from probmap.datasets.ros.scans import SCAN_TYPES
        from probmap.datasets.ros.summary import summarize_bag

        bag = laser_input(bag, data_dir)
        s = summarize_bag(bag)
        console = Console()
        table = Table(title=f"{bag.name}: ROS {s.ros_version} bag")
        for name, justify in (
            ("topic", "left"),
            ("type", "left"),
            ("count", "right"),
            ("frames", "left"),
            ("start (s)", "right"),
            ("duration (s)", "right"),
        ):
            table.add_column(name, justify=justify, overflow="fold")  # type: ignore[arg-type]
        for t in s.topics:
            table.add_row(
                t.topic,
                t.msgtype.replace("/msg/", "/"),
                f"{t.count:,}",
                ", ".join(t.frames) or "-",
                _seconds(t.start - s.start),
                _seconds(t.end - t.start),
            )
        console.print(table)
        rows = [
            ("messages", f"{s.messages:,}"),
            ("duration", f"{_seconds(s.duration)} s ({_seconds(s.start)} to {_seconds(s.end)})"),
            ("frames", ", ".join(s.frames) or "-"),
        ]
        for parent, child, static, count in s.tf_links:
            kind = "static" if static else f"{count:,} transforms"
            rows.append(("tf", f"{parent} -> {child} ({kind})"))
        scans = [t.topic for t in s.topics_of(SCAN_TYPES)]
        rows.append(("laser topics", ", ".join(scans) or "none"))
        print_summary(None, rows, justify="left", console=console)


def register(app: typer.Typer) -> None:
    """Attach ``probmap info``."""
    app.command("info", short_help="A ROS bag's topics, types, counts, frames and times.")(
        info_command
    )
