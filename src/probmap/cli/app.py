"""The ``probmap`` command line: parses arguments and delegates to the library.

Each command lives in its own module under ``probmap.cli`` and is imported only when the
command runs, so ``probmap --help`` and ``probmap --version`` stay fast (no numba, scipy or
matplotlib at start-up).
"""

from __future__ import annotations

import typer

from probmap import __version__

app = typer.Typer(
    name="probmap",
    help="Probabilistic robot mapping and SLAM: occupancy grids, localization, EKF/SEIF SLAM.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"probmap {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """Probabilistic robot mapping and SLAM."""


def main() -> None:
    """Console-script entry point."""
    from probmap.cli import IMPORTED_AT, register
    from probmap.cli.common import mark_process_start

    mark_process_start(IMPORTED_AT)
    register(app)
    app()
