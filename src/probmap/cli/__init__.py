"""probmap command line. Command modules register themselves in :func:`register`."""

from __future__ import annotations

import time as _time

# when the command line package was first imported: the start of a ``probmap`` process, up to
# the interpreter's own start-up (see :func:`probmap.cli.common.mark_process_start`)
IMPORTED_AT = _time.perf_counter()

import typer  # noqa: E402


def register(app: typer.Typer) -> None:
    """Attach every command module's commands to ``app``.

    Each module only defines thin typer functions whose bodies import the library lazily.
    """
    from probmap.cli import mapping

    mapping.register(app)
    from probmap.cli import evaluate

    evaluate.register(app)
    from probmap.cli import landmark_slam

    landmark_slam.register(app)
    from probmap.cli import laser_slam

    laser_slam.register(app)
    from probmap.cli import map_mapping

    map_mapping.register(app)
    from probmap.cli import localize

    localize.register(app)
    from probmap.cli import bag

    bag.register(app)
    from probmap.cli import semantic

    semantic.register(app)
    from probmap.cli import optimize

    optimize.register(app)
    from probmap.cli import datasets

    datasets.register(app)
