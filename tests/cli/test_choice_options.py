"""Word options (``--method``, ``--init``, ``--robust``, ``--robust-edges``): one check,
``cli.common.check_choice``, so every command refuses a bad word with the same one line."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.cli.common import check_choice

register(app)
runner = CliRunner()


def expected(option: str, value: str, choices: tuple[str, ...]) -> str:
    """The message, written out by hand for each count of choices (the reference)."""
    q = [f"'{c}'" for c in choices]
    if len(q) == 1:
        allowed = q[0]
    elif len(q) == 2:
        allowed = f"{q[0]} or {q[1]}"
    else:
        allowed = " ".join(f"{w}," for w in q[:-2]) + f" {q[-2]} or {q[-1]}"
    return f"{option} must be {allowed.strip()}, got '{value}'"


@pytest.mark.parametrize("choices", [("a",), ("a", "b"), ("a", "b", "c"), ("w", "x", "y", "z")])
def test_check_choice(choices):
    for c in (*choices, None):
        check_choice("--opt", c, choices)  # a listed word or no option passes
    for bad in ("", "A", "ab", choices[0] + " "):
        with pytest.raises(ValueError) as err:
            check_choice("--opt", bad, iter(choices))  # any iterable of words
        assert str(err.value) == expected("--opt", bad, choices)


@pytest.mark.parametrize(
    ("args", "option", "choices"),
    [
        (["map", "LOG", "--method", "mle"], "--method", ("log-odds", "map")),
        (["slam", "grid", "LOG", "--method", "icp"], "--method", ("graph", "rbpf")),
        (["optimize", "G", "--init", "chordal"], "--init", ("auto", "given", "lago")),
        (["optimize", "G", "--robust", "tukey"], "--robust", ("none", "huber", "cauchy", "dcs")),
        (["optimize", "G", "--robust-edges", "odometry"], "--robust-edges", ("all", "closures")),
    ],
)
def test_commands_refuse_a_bad_word_in_one_line(tmp_path, args, option, choices):
    log = tmp_path / "in.clf"
    log.write_text("")
    out = tmp_path / "out" / "x.g2o"
    argv = [str(log) if a in ("LOG", "G") else a for a in args]
    res = runner.invoke(app, [*argv, "-o", str(out)])
    assert res.exit_code == 1, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    bad = argv[argv.index(option) + 1]
    assert lines == [f"error: {expected(option, bad, choices)}"]
    assert not out.parent.exists()  # refused before any output
