"""The output rule every pipeline and command shares: check an output folder or ``PREFIX``
before any work, create nothing (the files are written later, all-or-nothing, by
:func:`probmap._atomic.atomic_outputs`)."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["check_output_folder", "check_output_prefix"]


def _check_folder(folder: Path, what: str) -> None:
    """``folder`` is usable for output: it is a writable folder, or it is missing and its
    nearest existing parent is a writable folder (it will be created when the files are
    written). Creates nothing."""
    p = folder
    while not p.exists() and not p.is_symlink() and p.parent != p:
        p = p.parent
    if not p.is_dir():
        if p == folder:
            raise NotADirectoryError(f"{what} {folder} exists and is not a folder")
        raise NotADirectoryError(f"{what} {folder}: {p} exists and is not a folder")
    if not os.access(p, os.W_OK | os.X_OK):
        raise PermissionError(f"{what} {folder}: {p} is not writable")


def check_output_folder(folder: str | os.PathLike[str]) -> Path:
    """The output rule for commands that write into a folder (``slam ekf|seif``, ``localize``,
    ``demo``): check ``folder`` before any work, create nothing.

    A missing folder (and its missing parents) is fine: it is created when the files are
    written (:func:`probmap._atomic.atomic_outputs`) and removed again if the command fails.

    Raises
    ------
    NotADirectoryError
        When ``folder``, or the nearest existing parent of it, is not a folder.
    PermissionError
        When that folder is not writable.
    """
    p = Path(folder)
    _check_folder(p, "output folder")
    return p


def check_output_prefix(prefix: str | os.PathLike[str], default_name: str | None = None) -> Path:
    """The output rule for commands that write ``PREFIX.*`` files or one named file (``map``,
    ``slam grid``, ``semantic``, ``fit-sensor-model``, ``optimize``, ...): check ``prefix``
    before any work and return the prefix to write; create nothing.

    - ``prefix`` naming an existing folder, or ending with a path separator (``outdir/``),
      means ``prefix/default_name``: the files go inside that folder under the command's
      default name.
    - A missing output folder is fine: it is created when the files are written
      (:func:`probmap._atomic.atomic_outputs`) and removed again if the command fails.

    Raises
    ------
    ValueError
        When ``prefix`` has no file name part and the command has no default name.
    NotADirectoryError, PermissionError
        When the output folder (or its nearest existing parent) is not a writable folder.
    """
    text = os.fspath(prefix)
    p = Path(prefix)
    if text.endswith(("/", os.sep)) or p.is_dir() or p.name in ("", ".", ".."):
        if default_name is None:
            raise ValueError(f"output prefix {text} needs a file name part")
        p = p / default_name
    folder = p.parent if str(p.parent) else Path(".")
    _check_folder(folder, "output folder")
    return p
