"""What a command records of its run beside its outputs: the resolved configuration, the
command line and the probmap version.

:func:`write_run_config` writes ``PREFIX.config.yaml`` as :func:`probmap.config.write_config`
does (``probmap_version``, ``config_class`` and every field) with the command line on a
comment line at the top, so that the file still loads back with
:func:`probmap.config.load_config` and, given to ``--config``, reproduces the run.
"""

from __future__ import annotations

import os
import shlex
import sys
from pathlib import Path
from typing import Any

__all__ = ["command_line", "config_over", "write_run_config"]


def command_line(argv: list[str] | None = None) -> str:
    """The command line of this process on one line, shell-quoted (``probmap semantic ...``);
    ``argv`` defaults to :data:`sys.argv`, whose first item is shown by its base name.

    >>> command_line(["/opt/venv/bin/probmap", "map", "my log.clf", "-o", "out"])
    "probmap map 'my log.clf' -o out"
    """
    args = list(sys.argv if argv is None else argv)
    if args:
        args[0] = Path(args[0]).name
    return shlex.join(args).replace("\r", "\\r").replace("\n", "\\n")


def write_run_config(path: str | os.PathLike[str], cfg: Any) -> Path:
    """Write the frozen config dataclass ``cfg`` as YAML to ``path`` atomically (inside the
    command's :func:`probmap._atomic.atomic_outputs` block, with its other outputs), preceded
    by a ``# command: ...`` comment line; returns the path."""
    from probmap.config import write_config

    return write_config(path, cfg, command=command_line())


def config_over(base: Any, path: Any = None, overrides: dict[str, Any] | None = None) -> Any:
    """The configuration a command runs with when its defaults are not its class's:
    the fields the YAML file ``path`` gives (checked by :func:`probmap.config.load_config`,
    whose errors name the file and the field) over the command's own ``base``, then the
    ``overrides`` whose value is not None (the options the user gave) on top."""
    import dataclasses

    import yaml

    from probmap.config import CLASS_KEY, VERSION_KEY, load_config

    cfg = base
    if path is not None:
        loaded = load_config(type(base), path)
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8")) or {}
        given = [k for k in data if k not in (VERSION_KEY, CLASS_KEY)]
        cfg = dataclasses.replace(base, **{k: getattr(loaded, k) for k in given})
    given_options = {k: v for k, v in (overrides or {}).items() if v is not None}
    return dataclasses.replace(cfg, **given_options) if given_options else cfg
