"""``probmap map`` and ``probmap demo`` (filled in by the occupancy grid work)."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    """Attach the mapping commands."""
