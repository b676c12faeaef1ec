"""``probmap datasets list`` and ``probmap datasets fetch`` (the registry and the downloads)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import typer

from probmap.cli.common import cli_errors

datasets_app = typer.Typer(
    help="Known datasets: list them, download the public ones.", no_args_is_help=True
)


@datasets_app.command("list", short_help="The registered datasets and whether they are present.")
def list_command(
    data_dir: Path | None = typer.Option(
        None, "--data-dir", "--dir", help="Data directory (default $PROBMAP_DATA)."
    ),
) -> None:
    """List the registered datasets and whether they are present in the data directory, and
    the names 'probmap datasets fetch' downloads."""
    with cli_errors():
        from rich.console import Console
        from rich.table import Table

        from probmap.datasets import fetch
        from probmap.datasets.registry import DATASETS
        from probmap.datasets.registry import data_dir as find_root

        console = Console()
        root = find_root(data_dir)
        table = Table(title=f"datasets (data directory: {root or 'not set'})")
        for col in ("name", "kind", "format", "present", "description"):
            table.add_column(col)
        for info in DATASETS.values():
            if info.relpath is None:
                present = "generated"
            elif root is None:
                present = "?"
            else:
                present = "yes" if (root / info.relpath).exists() else "no"
            table.add_row(info.name, info.kind, info.format, present, info.description)
        console.print(table)

        target = fetch.default_directory(data_dir)
        remote = Table(title=f"probmap datasets fetch NAME (into {target})")
        for col in ("name", "files", "present", "description"):
            remote.add_column(col)
        for d in fetch.DATASETS.values():
            have = sum((target / p).is_file() for p in d.files)
            present = "yes" if have == len(d.files) else "no" if have == 0 else f"{have} files"
            remote.add_row(d.name, str(len(d.files)), present, d.description)
        console.print(remote)


@datasets_app.command("fetch", short_help="Download the public datasets, checking their checksums.")
def fetch_command(
    names: list[str] = typer.Argument(
        ...,
        metavar="NAME",
        help="Dataset names (see 'probmap datasets list'; 'all' for every file) or files of "
        "the registry (e.g. pose-graphs/M3500.g2o).",
    ),
    directory: Path | None = typer.Option(
        None,
        "--dir",
        "--data-dir",
        help="Where to put the files (default: $PROBMAP_DATA, else the user cache folder).",
    ),
    base_url: str | None = typer.Option(
        None,
        "--base-url",
        help="Fetch every file from BASE/<place under the data directory> instead of its "
        "public address, e.g. a mirror (default: $PROBMAP_DATA_URL).",
    ),
) -> None:
    """Download public datasets from their public addresses, checking each file's sha256;
    a file already present with the right hash is not downloaded again."""
    with cli_errors():
        from rich.console import Console
        from rich.progress import (
            DownloadColumn,
            Progress,
            TaskID,
            TextColumn,
            TransferSpeedColumn,
        )

        from probmap.datasets import fetch

        for name in names:
            fetch.files_of(name)  # every name is checked before any download
        # absolute, as the fetched paths are (pooch's abspath)
        root = Path(os.path.abspath(os.path.expanduser(fetch.default_directory(directory))))
        fetched: list[fetch.FetchedFile] = []
        columns = (TextColumn("{task.description}"), DownloadColumn(), TransferSpeedColumn())
        console = Console(stderr=True)
        if console.is_terminal:
            bar: Any = Progress(*columns, console=console, transient=True)
        else:  # a log: a line every 10 % of each file
            from probmap.cli.common import LineProgress

            bar = LineProgress(unit="bytes", file=console.file)
        with bar:
            tasks: dict[str, TaskID] = {}

            def progress(place: str, done: int, total: int) -> None:
                if place not in tasks:
                    tasks[place] = bar.add_task(place, total=total or None)
                bar.update(tasks[place], completed=done, total=total or None)

            for name in names:
                fetched += fetch.fetch(name, root, base_url=base_url, progress=progress)
        seen: set[Path] = set()
        for f in fetched:
            if f.path in seen:
                continue
            seen.add(f.path)
            state = "downloaded" if f.downloaded else "present"
            typer.echo(f"{state:<10}  {f.size / 2**20:7.2f} MiB  {f.path.relative_to(root)}")
        n_new = sum(f.downloaded for f in fetched)
        typer.echo(
            f"{len(seen)} file{'' if len(seen) == 1 else 's'} in {root}, sha256 checked "
            f"({n_new} downloaded, "
            f"{len(seen) - n_new} already present)"
        )
        env = os.environ.get(fetch.DATA_ENV)
        if not env or Path(env).resolve() != root.resolve():
            typer.echo(f"to open them by name: export {fetch.DATA_ENV}={root}")


def register(app: typer.Typer) -> None:
    """Mount ``probmap datasets``."""
    app.add_typer(datasets_app, name="datasets")
