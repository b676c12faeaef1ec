"""mkdocs hooks: pages generated at build time from the code and the repository.

- ``<!-- cli-reference -->`` in a page becomes the ``--help`` of every ``probmap`` command,
  rendered from the typer app itself (so the reference cannot drift from the code).
- ``<!-- include: FILE -->`` becomes the text of ``FILE`` (relative to the repository root), for
  pages that show a file kept at the top of the repository (``BENCHMARKS.md``).

Nothing here reaches the network: the build works offline.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
CLI_MARK = "<!-- cli-reference -->"
INCLUDE = re.compile(r"<!-- include: ([\w./-]+) -->")


def _commands(command: Any, path: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], Any]]:
    """Every command of the click tree, depth first, groups before their commands."""
    found = [(path, command)]
    for name in sorted(getattr(command, "commands", {})):
        found += _commands(command.commands[name], (*path, name))
    return found


def cli_reference() -> str:
    """Markdown: one section per ``probmap`` command with its ``--help`` text."""
    import typer
    from typer.testing import CliRunner

    from probmap.cli import register
    from probmap.cli.app import app

    register(app)
    root = typer.main.get_command(app)
    runner = CliRunner()
    env = {"COLUMNS": "100", "TERM": "dumb", "NO_COLOR": "1"}
    parts = []
    for path, command in _commands(root):
        result = runner.invoke(app, [*path, "--help"], prog_name="probmap", env=env)
        if result.exit_code != 0:
            raise RuntimeError(f"probmap {' '.join(path)} --help failed: {result.output}")
        text = "\n".join(line.rstrip() for line in result.output.strip("\n").splitlines())
        title = " ".join(("probmap", *path))
        level = "##" if len(path) <= 1 else "###"
        parts.append(f"{level} `{title}`\n\n```text\n{text}\n```\n")
        del command
    return "\n".join(parts)


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    if CLI_MARK in markdown:
        markdown = markdown.replace(CLI_MARK, cli_reference())

    def include(match: re.Match[str]) -> str:
        text = (REPO / match.group(1)).read_text(encoding="utf-8")
        # the included file's own title is the page's
        return re.sub(r"\A# .*\n", "", text)

    return INCLUDE.sub(include, markdown)
