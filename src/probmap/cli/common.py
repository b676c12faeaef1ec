"""Helpers shared by CLI commands: one-line errors and non-zero exits, never tracebacks."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import typer


class CliError(Exception):
    """An error the CLI reports on one line."""


@contextmanager
def cli_errors() -> Iterator[None]:
    """Turn expected library errors into a one-line message on stderr and exit code 1."""
    try:
        yield
    except (CliError, ValueError, OSError, EOFError, KeyError) as exc:
        msg = str(exc) or exc.__class__.__name__
        if isinstance(exc, OSError) and exc.filename and str(exc.filename) not in msg:
            msg = f"{exc.filename}: {msg}"
        typer.echo(f"error: {msg}", err=True)
        raise typer.Exit(1) from None
