"""Option groups: one parameter in the code, its options on the command line, in place."""

from __future__ import annotations

import re

import pytest
import typer
from typer.testing import CliRunner

from probmap.cli.options import option_group, ros_bag_options, with_option_groups


def _pair(a: int, b: str | None) -> tuple[int, str | None]:
    return (a, b)


def _app(seen: list) -> typer.Typer:
    app = typer.Typer()

    @app.command()
    @with_option_groups
    def cmd(
        first: int = typer.Option(0, "--first"),
        both: tuple = option_group(
            _pair,
            a=(int, typer.Option(7, "--a", help="The a.")),
            b=(str | None, typer.Option(None, "--b", help="The b.")),
        ),
        last: bool = typer.Option(False, "--last"),
    ) -> None:
        seen.append((first, both, last))

    @app.command()
    def other() -> None:  # a second command keeps "cmd" a subcommand
        pass

    return app


def test_group_combines_its_options_and_keeps_the_others():
    seen: list = []
    res = CliRunner().invoke(_app(seen), ["cmd", "--b", "x", "--first", "3", "--last"])
    assert res.exit_code == 0, res.output
    assert seen == [(3, (7, "x"), True)]
    res = CliRunner().invoke(_app(seen), ["cmd", "--a", "2"])
    assert res.exit_code == 0, res.output
    assert seen[-1] == (0, (2, None), False)


def test_group_is_listed_in_place_in_help():
    res = CliRunner().invoke(_app([]), ["cmd", "--help"], env={"COLUMNS": "120"})
    assert res.exit_code == 0, res.output
    order = [m for m in re.findall(r"--(first|a|b|last)\b", res.output)]
    assert order == ["first", "a", "b", "last"]
    assert "The a." in res.output and "[default: 7]" in res.output


def test_group_rejects_a_bad_value_like_any_option():
    res = CliRunner().invoke(_app([]), ["cmd", "--a", "many"])
    assert res.exit_code == 2


def test_repeated_name_is_refused():
    def cmd(a: int = 0, g: object = option_group(dict, a=(int, typer.Option(1, "--a")))) -> None:
        pass

    with pytest.raises(TypeError, match="repeats"):
        with_option_groups(cmd)


def test_ros_bag_options_give_open_scans_bag_options():
    group = ros_bag_options()
    names = [n for n, _, _ in group.options]
    assert names == ["scan_topic", "odom_topic", "fixed_frame", "laser_frame"]
    values = dict(zip(names, ["/scan", "/odom", "map", "laser"], strict=True))
    assert group.combine(**values) == values
