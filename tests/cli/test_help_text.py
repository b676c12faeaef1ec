"""Every command's ``--help`` reads well in an 80-column terminal: no line is wider, no help
text is squeezed into a narrow column of one to three words a line, and every option with a
default shows it."""

from __future__ import annotations

import re

import pytest
from typer.main import get_command
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app

register(app)
ROOT = get_command(app)


def _walk(cmd, path):
    yield path, cmd
    for name, sub in getattr(cmd, "commands", {}).items():
        yield from _walk(sub, [*path, name])


COMMANDS = [path for path, _ in _walk(ROOT, [])]


def _help(path: list[str]) -> str:
    res = CliRunner().invoke(app, [*path, "--help"], env={"COLUMNS": "80"}, terminal_width=80)
    assert res.exit_code == 0, res.output
    return res.output


def _squeezed(text: str) -> list[str]:
    """Lines of a wrapped help paragraph (a line followed by more of the same paragraph,
    at the same indentation) that hold three words or fewer in under 30 characters."""
    lines = text.splitlines()
    bad = []
    for line, nxt in zip(lines, lines[1:], strict=False):
        indent = len(line) - len(line.lstrip())
        nxt_indent = len(nxt) - len(nxt.lstrip())
        words = line.split()
        continued = nxt.strip() and nxt_indent == indent and indent >= 2
        short = 0 < len(words) <= 3 and len(line.strip()) < 30
        if continued and short and not line.strip().startswith("-"):
            bad.append(line)
    return bad


@pytest.mark.parametrize("path", COMMANDS, ids=lambda p: " ".join(p) or "probmap")
def test_help_fits_80_columns_without_squeezed_lines(path):
    text = _help(path)
    assert max(len(line) for line in text.splitlines()) <= 80
    assert _squeezed(text) == []
    # the options' help starts by column 34: 46 or more characters a line for the help
    starts = [
        m.end() for m in map(re.compile(r"^  -\S.*?\S {2,}(?=\S)").match, text.splitlines()) if m
    ]
    assert starts, "no option lines in the plain two-column layout"
    assert max(starts) <= 34, text


def test_squeeze_check_catches_a_narrow_column():
    narrow = "    rbpf: number of\n    particles .\n    [default: 30]\n"
    assert _squeezed(narrow) == ["    rbpf: number of", "    particles ."]
    assert _squeezed("  one line of help that is long enough to read well\n") == []


def _options(path):
    cmd = ROOT
    for name in path:
        cmd = cmd.commands[name]
    ctx = ROOT.make_context("probmap", ["--help"], resilient_parsing=True)
    ctx = type(ctx)(cmd, info_name=" ".join(path))
    for p in cmd.params:
        if p.param_type_name == "option" and not p.hidden:
            yield p, p.get_help_record(ctx)


@pytest.mark.parametrize("path", COMMANDS, ids=lambda p: " ".join(p) or "probmap")
def test_every_default_is_shown(path):
    """An option with a default (other than an off flag or None, "not given") states it, in
    typer's ``[default: ...]`` or in its own words; and no help ends in a stray " ." (the
    trace of a ``[default: ...]`` that rich markup swallowed)."""
    for p, (_, help_text) in _options(path):
        assert not re.search(r"\s\.$", help_text), (p.opts, help_text)
        if p.default is None or (p.is_flag and p.default is False) or p.name in ("help",):
            continue
        assert "default" in help_text.lower(), (path, p.opts, help_text)


def test_command_lists_are_not_cut_mid_sentence():
    """Every command of a group's list has a whole one-line summary (no "...")."""
    for path in COMMANDS:
        text = _help(path)
        if "Commands:" in text:
            listing = text.split("Commands:", 1)[1]
            assert "..." not in listing, (path, listing)


def test_slam_help_covers_grid_and_landmark_slam():
    text = " ".join(_help(["slam"]).split())
    assert "Grid SLAM (grid)" in text and "--method rbpf" in text
    assert "Landmark SLAM (ekf, seif, graphslam, fastslam, compare)" in text
