"""The README's Python API example runs as printed and builds the map ``probmap map`` builds;
the command table of the docs names every command with options that exist; the pictures and
imports of the README and the docs pages are real."""

from __future__ import annotations

import functools
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
DOCS = README.parent / "docs"
COMMANDS_PAGE = DOCS / "guide" / "commands.md"


def user_pages() -> list[Path]:
    """The README and every page of the docs site."""
    return [README, *sorted(DOCS.rglob("*.md"))]


def api_block() -> str:
    text = README.read_text(encoding="utf-8")
    section = text.split("## Python API in ten lines", 1)[1]
    m = re.search(r"```python\n(.*?)```", section, flags=re.DOTALL)
    assert m, "no python block under 'Python API in ten lines'"
    return m.group(1)


def test_api_example_runs_and_matches_the_cli(shared_data, tmp_path, monkeypatch):
    from probmap.grid.io import load_npz
    from probmap.pipelines import MappingConfig, map_log

    log = shared_data("intel-research-lab/intel-corrected.log.gz")
    shutil.copy(log, tmp_path / "intel-corrected.log.gz")
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(api_block(), "README.md", "exec"), namespace)  # noqa: S102 - our own README
    grid = load_npz(tmp_path / "intel.npz")
    cli = map_log(log, MappingConfig(resolution=0.05)).grid
    # the same cells, the same values (the CLI's grid is cropped to what it observed)
    assert grid.spec.shape[0] < 1000 and grid.spec.shape[1] < 1000  # no 181 m starburst
    crop = grid.cropped()
    assert crop.spec.shape == cli.spec.shape
    np.testing.assert_allclose(crop.spec.origin, cli.spec.origin)
    np.testing.assert_array_equal(crop.log_odds, cli.log_odds)
    assert namespace["p"].shape == grid.spec.shape


# ----------------------------------------------------------------------------- command table
def command_table() -> list[str]:
    """The first cell of every row of the table under '## Command line' of the docs' commands
    page, ``\\|`` unescaped."""
    text = COMMANDS_PAGE.read_text(encoding="utf-8")
    section = text.split("## Command line", 1)[1].split("\n\n", 2)[1]
    rows = [line for line in section.splitlines() if line.startswith("| `")]
    cells = [row.replace("\\|", "\0").split("|")[1].replace("\0", "|") for row in rows]
    return cells


def quoted_commands(cell: str) -> list[str]:
    return [m for m in re.findall(r"`([^`]*)`", cell) if m.startswith("probmap")]


def resolve(group, words: list[str]):
    """The click commands a README command line names (``slam ekf|seif`` names two) and the
    number of words the subcommand path took."""
    commands, used = [group], 0
    while words[used:] and all(hasattr(c, "commands") for c in commands):
        names = words[used].split("|")
        if not all(n in c.commands for c in commands for n in names):
            break
        commands = [c.commands[n] for c in commands for n in names]
        used += 1
    return commands, used


@functools.cache
def cli_tree():
    """The CLI app with its commands registered, and its click command tree (built once)."""
    import typer

    from probmap.cli import register
    from probmap.cli.app import app

    register(app)
    return app, typer.main.get_command(app)


def leaf_paths(command, path=()):
    if not hasattr(command, "commands"):
        return [path]
    return [p for name, c in command.commands.items() for p in leaf_paths(c, (*path, name))]


def split_line(root, line: str):
    """The commands a README command line names, their paths and the rest of the line."""
    words = line.split()[1:]
    commands, used = resolve(root, [w.strip("[]") for w in words])
    paths: list[tuple[str, ...]] = [()]
    for alternatives in (w.split("|") for w in words[:used]):
        paths = [(*p, a) for p in paths for a in alternatives]
    return commands, paths, " ".join(words[used:])


@functools.cache
def help_text(path: tuple[str, ...]) -> str:
    from typer.testing import CliRunner

    app, _ = cli_tree()
    res = CliRunner().invoke(app, [*path, "--help"], env={"COLUMNS": "200"})
    assert res.exit_code == 0, (path, res.output)
    return res.output


COMMAND_LINES = [q for cell in command_table() for q in quoted_commands(cell)]


def test_the_table_lists_every_command():
    _, root = cli_tree()
    assert len(COMMAND_LINES) >= 15, COMMAND_LINES  # the table was found and read
    named = {path for line in COMMAND_LINES for path in split_line(root, line)[1]}
    missing = [" ".join(p) for p in leaf_paths(root) if p not in named]
    assert not missing, f"commands missing from docs/guide/commands.md's table: {missing}"


@pytest.mark.parametrize("line", COMMAND_LINES)
def test_command_line_in_the_table_parses(line):
    _, root = cli_tree()
    commands, paths, rest = split_line(root, line)
    options = re.findall(r"(?<![\w-])(--?[a-zA-Z][\w-]*)", rest)
    for command, path in zip(commands, paths, strict=True):
        # a group (probmap, probmap slam) only with --help or --version
        if hasattr(command, "commands"):
            assert options and set(options) <= {"--help", "--version"}, (
                f"README: {line!r} names no command of the CLI after {path}"
            )
        declared = {"--help"}
        for param in command.params:
            declared.update(param.opts)
            declared.update(param.secondary_opts)
        listed = set(re.findall(r"(?<![\w-])(--?[a-zA-Z][\w-]*)", help_text(path)))
        for option in options:
            assert option in declared, f"README: {line!r}: {option} is no option of {path}"
            assert option in listed, f"README: {line!r}: `--help` of {path} lacks {option}"
        # a choice the README spells out (--poses corrected|odometry) is in the help text
        for option, choices in re.findall(r"(--[\w-]+) ([a-z][\w-]*(?:\|[a-z][\w-]*)+)", rest):
            for choice in choices.split("|"):
                assert re.search(rf"(?<![\w-]){re.escape(choice)}(?![\w-])", help_text(path)), (
                    f"README: {line!r}: {choice} of {option} is not in `--help` of {path}"
                )


def test_resolve_reads_alternatives_and_stops_at_arguments():
    _, root = cli_tree()
    commands, used = resolve(root, ["slam", "ekf|seif", "DATASET", "-o", "DIR"])
    assert [c.name for c in commands] == ["ekf", "seif"] and used == 2
    commands, used = resolve(root, ["map", "LOG", "--config", "FILE.yaml"])
    assert [c.name for c in commands] == ["map"] and used == 1
    commands, used = resolve(root, ["slam", "nosuch", "DATASET"])
    assert [c.name for c in commands] == ["slam"] and used == 1


# ----------------------------------------------------------------------------- pictures
def test_every_linked_picture_exists():
    """Every picture the README and the docs pages show or name exists and is a PNG."""
    checked = 0
    for page in user_pages():
        text = page.read_text(encoding="utf-8")
        targets = re.findall(r"!\[[^\]]*\]\(([^)\s]+\.png)\)", text)
        paths = [(page.parent / t).resolve() for t in targets]
        # a path written out in the text (`docs/mcl_intel.png`) is relative to the repository
        paths += [README.parent / n for n in re.findall(r"(?<![\w/.])(docs/[\w./-]+\.png)", text)]
        for path in paths:
            assert path.is_file(), f"{page.name} shows {path}, which does not exist"
            with open(path, "rb") as f:
                assert f.read(8) == b"\x89PNG\r\n\x1a\n", f"{path} is not a PNG file"
            checked += 1
    assert checked >= 15, checked  # the pictures were found


# ----------------------------------------------------------------------------- architecture
def test_the_architecture_tree_names_every_module_and_only_those():
    """The package tree that docs/architecture.md draws names exactly the package's files: none
    that does not exist, and every module that does (so that it says where each thing lives)."""
    text = (README.parent / "docs" / "architecture.md").read_text(encoding="utf-8")
    m = re.search(r"```\n(src/probmap/.*?)```", text, flags=re.DOTALL)
    assert m, "no package tree in docs/architecture.md"
    src = README.parent / "src" / "probmap"
    package, named = "", []
    for line in m.group(1).splitlines():
        head = re.match(r"\s+(\w+(?:/\w+)*)/(?:\s|$)", line)  # a (sub)package: datasets/ros/
        if head:
            package = head.group(1)
        for name in re.findall(r"(?<![\w.])(\w+\.py|py\.typed)\b", line):
            named.append(src / package / name)
    assert len(named) > 100, named  # the tree was read
    missing = [str(p.relative_to(src)) for p in named if not p.is_file()]
    assert not missing, f"docs/architecture.md names modules that do not exist: {missing}"
    unnamed = sorted(str(p.relative_to(src)) for p in src.rglob("*.py") if p not in set(named))
    assert not unnamed, f"docs/architecture.md does not say where these live: {unnamed}"


# ----------------------------------------------------------------------------- imports
def readme_imports() -> list[str]:
    """Every ``from probmap... import ...`` line of the Python blocks of the README and the
    docs pages."""
    text = "\n".join(p.read_text(encoding="utf-8") for p in user_pages())
    lines = set()
    for block in re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL):
        for line in block.splitlines():
            code = line.split("#", 1)[0].strip()
            if code.startswith(("from probmap", "import probmap")):
                lines.add(code)
    return sorted(lines)


def test_readme_imports_are_the_new_paths():
    """The documented imports work and none goes through a deprecation shim."""
    import warnings

    lines = readme_imports()
    assert len(lines) >= 20, lines  # the blocks were read
    for line in lines:
        with warnings.catch_warnings():
            warnings.simplefilter("error", DeprecationWarning)
            exec(line, {})  # noqa: S102 - our own README
