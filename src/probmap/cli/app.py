"""The ``probmap`` command line: parses arguments and delegates to the library.

Each command lives in its own module under ``probmap.cli`` and is imported only when the
command runs, so ``probmap --help`` and ``probmap --version`` stay fast (no numba, scipy or
matplotlib at start-up).
"""

from __future__ import annotations

import sys
from typing import Any

import typer

from probmap import __version__

app = typer.Typer(
    name="probmap",
    help="Probabilistic robot mapping and SLAM: occupancy grids, grid and landmark SLAM, "
    "localization, pose graphs.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    # click's plain help: paragraphs reflowed to the terminal (COLUMNS), options in two
    # columns with the help 45 or more characters wide at 80 columns, defaults shown
    rich_markup_mode=None,
    context_settings={"max_content_width": 100},
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


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _nothing_written(unless_said_since: int | None = None) -> None:
    """The line of an interrupt that came before a command could say what it wrote (none
    when the command said its own since ``unless_said_since`` lines)."""
    from probmap.cli.common import interrupts_said, say_interrupted

    if unless_said_since is None or interrupts_said() == unless_said_since:
        say_interrupted("interrupted: nothing written")


def _one_line_warning(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    file: Any = None,
    line: str | None = None,
) -> None:
    """A library warning as the command line shows it: ``warning: MESSAGE``, one line,
    without Python's source file and line."""
    text = " ".join(str(message).split())
    print(f"warning: {text}", file=sys.stderr if file is None else file)


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point (``argv``: the arguments, ``sys.argv[1:]`` by default).

    SIGTERM is a Ctrl-C from the start, and an interrupt at any moment ends with one line
    and exit code 130: the commands say what they wrote; one that came before a command
    started (while the arguments were read) says ``interrupted: nothing written``."""
    import signal
    import warnings

    previous = signal.signal(signal.SIGTERM, _interrupt)
    shown = warnings.showwarning
    warnings.showwarning = _one_line_warning
    said = 0
    try:
        try:
            from probmap.cli import IMPORTED_AT, register
            from probmap.cli.common import interrupts_said, mark_process_start

            said = interrupts_said()
            mark_process_start(IMPORTED_AT)
            register(app)
            app(args=argv, prog_name="probmap")
        except KeyboardInterrupt:  # before typer's own handling (building the commands)
            _nothing_written()
            raise SystemExit(130) from None
        except SystemExit as exc:
            if exc.code == 130:  # typer ends a Ctrl-C while it reads arguments silently
                _nothing_written(unless_said_since=said)
            raise
    finally:
        signal.signal(signal.SIGTERM, previous)
        warnings.showwarning = shown
