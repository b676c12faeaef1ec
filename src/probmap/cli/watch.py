"""Watching and stopping a long run: ``--viz`` / ``--viz-save`` (the rerun live view) and
Ctrl-C that stops cleanly (``--save-partial``), shared by ``probmap map`` and landmark SLAM."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import typer


# the option factories here have the same form as those of probmap.cli.options: one per option
def viz_option(help: str = "Watch the run in the rerun viewer (extra 'viz').") -> Any:
    """``--viz``: show the run in the rerun viewer (``help`` says what it shows)."""
    return typer.Option(False, "--viz", help=help)


def viz_save_option(
    help: str = "Record the live view into FILE.rrd (open it later with 'rerun FILE.rrd').",
) -> Any:
    """``--viz-save FILE.rrd``: record the live view (checked by :func:`open_view`)."""
    return typer.Option(None, "--viz-save", help=help)


def save_partial_option(
    help: str = "On Ctrl-C, stop and write the results of the part run so far (exit 130); a "
    "second Ctrl-C aborts without writing.",
) -> Any:
    """``--save-partial/--no-save-partial`` (default on): what Ctrl-C does
    (:func:`stop_on_ctrl_c`)."""
    return typer.Option(True, "--save-partial/--no-save-partial", help=help)


def live_view_options() -> Any:
    """``--viz``, ``--viz-save FILE.rrd`` and ``--save-partial/--no-save-partial`` (default
    on): the same three options on every command with a live view (an
    :func:`~probmap.cli.options.option_group`). The command gets them as one dict,
    ``{"viz": ..., "viz_save": ..., "save_partial": ...}``, the keywords of the functions that
    run it (:func:`probmap.cli.landmark_slam.run_and_report`)."""
    from probmap.cli.options import option_group

    return option_group(
        dict,
        viz=(bool, viz_option()),
        viz_save=(Path | None, viz_save_option()),
        save_partial=(bool, save_partial_option()),
    )


def open_view(title: str, viz: bool, viz_save: Path | None) -> Any:
    """The :class:`~probmap.viz.live.LiveView` of ``--viz`` / ``--viz-save`` (None without
    either); the recording's name and folder are checked before any work.

    Raises
    ------
    ValueError
        ``viz_save`` does not end in ``.rrd``.
    probmap.errors.MissingExtraError
        rerun is not installed (the message names the ``viz`` extra).
    """
    if not viz and viz_save is None:
        return None
    from probmap.pipelines import check_output_folder
    from probmap.viz.live import LiveView

    if viz_save is not None:
        if viz_save.suffix != ".rrd":
            raise ValueError(f"--viz-save {viz_save}: a recording is saved as FILE.rrd")
        check_output_folder(viz_save.parent if str(viz_save.parent) else Path("."))
    return LiveView(title, save=viz_save, spawn=viz)


@contextmanager
def stop_on_ctrl_c(enabled: bool, unit: str = "step") -> Iterator[Callable[[], bool] | None]:
    """While active, the first Ctrl-C (SIGINT) or SIGTERM asks the run to stop after the
    current ``unit`` (the yielded callable then returns True) and says so on stderr; a second
    one raises KeyboardInterrupt as usual. Disabled, or off the main thread, it yields None and
    changes nothing. The previous handler is restored on exit."""
    import signal
    import threading

    if not enabled or threading.current_thread() is not threading.main_thread():
        yield None
        return
    asked = [False]

    def handler(signum: int, frame: Any) -> None:
        if asked[0]:
            raise KeyboardInterrupt
        asked[0] = True
        name = "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name
        print(
            f"\n{name}: stopping after this {unit} and writing the results so far "
            "(Ctrl-C again to abort)",
            file=sys.stderr,
        )

    previous = signal.signal(signal.SIGINT, handler)
    previous_term = signal.signal(signal.SIGTERM, handler)  # as systemd, Docker, Slurm stop
    try:
        yield lambda: asked[0]
    finally:
        signal.signal(signal.SIGINT, previous)
        signal.signal(signal.SIGTERM, previous_term)


def recorded_rows(viz_save: Path | None) -> list[tuple[str, str]]:
    """The summary's row naming the ``--viz-save`` recording and how to replay it (none
    without one)."""
    return [] if viz_save is None else [("recorded", f"{viz_save} (rerun {viz_save})")]


@contextmanager
def view_discarded_on_error(view: Any) -> Iterator[None]:
    """Inside: an error or a Ctrl-C that ends the block discards the live view ``view`` (None:
    no view) before it goes on; a Ctrl-C then ends the command with "interrupted: nothing
    written" and exit code 130 (the outputs are all or none: none)."""
    try:
        yield
    except BaseException as exc:
        if view is not None:
            view.close(keep=False)
        if isinstance(exc, KeyboardInterrupt):
            interrupted_exit(0, 0, "steps", wrote=False)
        raise


def interrupted_exit(done: int, total: int, unit: str, wrote: bool) -> None:
    """After a Ctrl-C: one line on stderr saying what was written, then exit code 130."""
    from probmap.cli.common import say_interrupted

    if wrote:
        msg = f"interrupted: wrote the results of the first {done:,} of {total:,} {unit}"
    else:
        msg = "interrupted: nothing written"
    say_interrupted(msg)
    raise typer.Exit(130)
