"""The options several commands share, each declared once.

Single options are factories (``config: Path | None = config_option("...")``). Options that
always travel together (a ROS bag's topics and frames; the live view) form an
:func:`option_group`: the command lists one parameter whose default is the group, and
:func:`with_option_groups` expands it, in place, into the group's options for typer, then
hands the command the group's one combined value. ``--help`` lists the same options in the
same order as if each had been written out. The live view's options and their group are in
:mod:`probmap.cli.watch`, the landmark commands' in :mod:`probmap.cli.landmark_slam`.

A command's own options (one command each) stay in its signature, where typer reads them; runs
of different options written alike (``x: float | None = typer.Option(None, "--x", help=...)``)
are what ``duplicates`` still lists as same-shape pairs among the commands: distinct options,
not repeats.

Command modules import it as ``opt`` (``from probmap.cli import options as opt``). It imports
nothing beyond typer and the standard library: ``probmap --help`` stays fast.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar, get_type_hints

import typer

F = TypeVar("F", bound=Callable[..., Any])


@dataclass(frozen=True)
class OptionGroup:
    """Typer options that one command parameter stands for (see :func:`option_group`).

    Attributes
    ----------
    options : tuple of (str, type, typer option)
        Each option's parameter name, annotation and ``typer.Option``, in ``--help`` order.
    combine : callable
        Called with the options' values as keywords; its result is what the command gets.
    """

    options: tuple[tuple[str, Any, Any], ...]
    combine: Callable[..., Any]


def option_group(combine: Callable[..., Any], **options: tuple[Any, Any]) -> Any:
    """A group of options, used as the default of the one parameter it stands for.

    Parameters
    ----------
    combine : callable
        Turns the options' values (keywords named as the options) into the parameter's value.
    **options : (type, typer option)
        Each option's annotation and ``typer.Option``, in the order ``--help`` lists them.

    Returns
    -------
    OptionGroup
        Typed ``Any`` so that it can stand as the default of a parameter of any type;
        :func:`with_option_groups` on the command expands it.
    """
    return OptionGroup(tuple((name, ann, opt) for name, (ann, opt) in options.items()), combine)


def with_option_groups(command: F) -> F:
    """The typer command ``command`` with each parameter whose default is an
    :class:`OptionGroup` replaced, at its place, by the group's options; a call combines their
    values back into that parameter. Decorate the function before typer registers it.

    Raises
    ------
    TypeError
        Two groups (or a group and the command) name the same parameter.
    """
    sig = inspect.signature(command)
    hints = get_type_hints(command, include_extras=True)
    params: list[inspect.Parameter] = []
    groups: dict[str, OptionGroup] = {}
    for p in sig.parameters.values():
        if not isinstance(p.default, OptionGroup):
            params.append(p.replace(annotation=hints.get(p.name, p.annotation)))
            continue
        groups[p.name] = p.default
        kind = inspect.Parameter.KEYWORD_ONLY
        params += [
            inspect.Parameter(n, kind, default=o, annotation=a) for n, a, o in p.default.options
        ]
    names = [p.name for p in params]
    if len(set(names)) != len(names):
        raise TypeError(f"{command.__name__}: an option group repeats a parameter name")

    @functools.wraps(command)
    def expanded(**kwargs: Any) -> Any:
        for name, group in groups.items():
            values = {n: kwargs.pop(n) for n, _, _ in group.options}
            kwargs[name] = group.combine(**values)
        return command(**kwargs)

    # keyword-only parameters may follow ones with defaults or none in any order
    fixed = [p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for p in params]
    expanded.__signature__ = sig.replace(parameters=fixed)  # type: ignore[attr-defined]
    expanded.__annotations__ = {p.name: p.annotation for p in fixed}
    expanded.__annotations__["return"] = hints.get("return", sig.return_annotation)
    return expanded  # type: ignore[return-value]


def config_option(help: str) -> Any:
    """``--config FILE``: a YAML file of the command's configuration fields; ``help`` names
    the configuration and what the other options do to it."""
    return typer.Option(None, "--config", help=help)


def output_option(help: str, default: Any = ...) -> Any:
    """``-o/--output``: where the command writes (required unless ``default`` is given)."""
    return typer.Option(default, "-o", "--output", help=help)


def data_dir_option() -> Any:
    """``--data-dir DIR``: where a dataset name given as the input is found, on every command
    that takes one (``$PROBMAP_DATA`` when not given, else ``../shared/data``)."""
    return typer.Option(
        None,
        "--data-dir",
        help="Where dataset names are found [default: $PROBMAP_DATA, else ../shared/data].",
    )


def skip_bad_lines_option() -> Any:
    """``--skip-bad-lines``: the same option, with the same meaning, on every command that
    reads a laser log."""
    return typer.Option(
        False,
        "--skip-bad-lines",
        help="Skip and count malformed or physically implausible log lines instead of failing.",
    )


def resolution_option(help: str = "Cell size in metres [default: 0.05].") -> Any:
    """``-r/--resolution``: the map's cell size, metres (None: the configuration's)."""
    return typer.Option(None, "--resolution", "-r", help=help)


def max_range_option(help: str) -> Any:
    """``--max-range``: the sensor's max range, metres (None: the log's)."""
    return typer.Option(None, "--max-range", help=help)


def poses_option(help: str) -> Any:
    """``--poses``: which poses of a log to use (``help`` lists the choices)."""
    return typer.Option(None, "--poses", help=help)


def p_hit_option(help: str) -> Any:
    """``--p-hit``: the inverse sensor model's p(occupied) at a beam's endpoint."""
    return typer.Option(None, "--p-hit", help=help)


def p_miss_option(help: str) -> Any:
    """``--p-miss``: the inverse sensor model's p(occupied) along a beam."""
    return typer.Option(None, "--p-miss", help=help)


def max_clear_option(help: str) -> Any:
    """``--max-clear``: the free space a max-range (no-return) reading clears, metres."""
    return typer.Option(None, "--max-clear", help=help)


def particles_option(help: str) -> Any:
    """``-n/--particles``: how many particles a filter runs (None: the configuration's)."""
    return typer.Option(None, "--particles", "-n", help=help)


def seed_option(help: str = "Random seed [default: 0].") -> Any:
    """``--seed``: the random seed of a sampling method (None: the configuration's)."""
    return typer.Option(None, "--seed", help=help)


def tum_option(
    help: str = "Also write trajectory.tum: the trajectory in the TUM format (evo_ape, evo_rpe).",
) -> Any:
    """``--tum``: also write the trajectory in the TUM format (``help`` names the file)."""
    return typer.Option(False, "--tum", help=help)


def bag_options_of(
    scan_topic: str | None,
    odom_topic: str | None,
    fixed_frame: str | None,
    laser_frame: str | None,
) -> dict[str, Any]:
    """The ``bag_options`` of :func:`probmap.datasets.open_scans` from the four options."""
    return {
        "scan_topic": scan_topic,
        "odom_topic": odom_topic,
        "fixed_frame": fixed_frame,
        "laser_frame": laser_frame,
    }


def ros_bag_options() -> Any:
    """``--scan-topic``, ``--odom-topic``, ``--fixed-frame``, ``--laser-frame``: how every
    command that reads a laser log picks a ROS bag's topics and frames; the command gets the
    ``bag_options`` dict of :func:`probmap.datasets.open_scans` (:func:`bag_options_of`)."""
    str_or_none = str | None
    return option_group(
        bag_options_of,
        scan_topic=(
            str_or_none,
            typer.Option(
                None,
                "--scan-topic",
                help="ROS bag: LaserScan/MultiEchoLaserScan topic (default: the only one).",
            ),
        ),
        odom_topic=(
            str_or_none,
            typer.Option(
                None,
                "--odom-topic",
                help="ROS bag: nav_msgs/Odometry topic (default: the only one).",
            ),
        ),
        fixed_frame=(
            str_or_none,
            typer.Option(
                None,
                "--fixed-frame",
                help="ROS bag: world frame of the poses (default: odometry frame, map or odom).",
            ),
        ),
        laser_frame=(
            str_or_none,
            typer.Option(
                None,
                "--laser-frame",
                help="ROS bag: the scans' frame (default: their header.frame_id).",
            ),
        ),
    )
