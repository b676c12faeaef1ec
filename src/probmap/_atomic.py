"""Atomic file writes: a temporary file in the target's folder, fsync, then ``os.replace``.

A reader never sees a half-written file: either the old file (or none) or the complete new one.
If the writer raises, the temporary file is removed and the target is untouched. New files get the
mode a plain ``open(path, "w")`` gives (0o666 less the umask: 0644 under the usual umask 022).

This module is the package's one writer of output files:

- :func:`atomic_write` / :func:`atomic_save`: one file, written through an open file object;
- :func:`atomic_files`: several files, all or nothing;
- :func:`atomic_path`: one file or folder written by a library that wants a *path*
  (``savefig``, ``np.savetxt``, a ROS bag writer).
"""

from __future__ import annotations

import os
import secrets
import shutil
import tempfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager, suppress
from pathlib import Path
from typing import IO, Any

__all__ = ["atomic_files", "atomic_path", "atomic_save", "atomic_write"]

_WRITE_MODES = ("w", "wt", "wb")


def _make_temp(path: Path) -> tuple[int, str]:
    """Create ``.NAME.XXXX.tmp`` beside ``path``.

    Opened with mode 0o666 so that the process umask applies, as for a plain ``open(path, "w")``
    (``tempfile.mkstemp`` would give 0o600).
    """
    folder = path.parent
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    for _ in range(100):
        tmp = folder / f".{path.name}.{secrets.token_hex(4)}.tmp"
        try:
            return os.open(tmp, flags, 0o666), str(tmp)
        except FileExistsError:  # pragma: no cover - 32 random bits collided
            continue
        except OSError as exc:
            raise _naming(exc, path) from None
    raise FileExistsError(f"cannot create a temporary file for {path}")  # pragma: no cover


def _naming(exc: OSError, path: Path) -> OSError:
    """The same kind of error, with a message that names the target and its folder."""
    reason = exc.strerror or str(exc)
    return type(exc)(exc.errno, f"cannot write {path}: {reason} ({path.parent})", str(path))


def _sync_folder(folder: Path) -> None:
    """Make the rename durable (POSIX); best effort where folders cannot be opened."""
    if os.name != "posix":  # pragma: no cover
        return
    with suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


@contextmanager
def atomic_write(
    path: str | os.PathLike[str], mode: str = "wb", *, encoding: str | None = None
) -> Iterator[IO[Any]]:
    """Open a temporary file next to ``path``; on a clean exit it replaces ``path`` atomically.

    Parameters
    ----------
    path : path-like
        The file to (re)write.
    mode : {"wb", "w", "wt"}
        Binary or text.
    encoding : str, optional
        Text encoding (text mode only; default UTF-8).

    Raises
    ------
    OSError
        When the folder does not exist or is not writable; the message names ``path``.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> target = pathlib.Path(tempfile.mkdtemp()) / "hello.txt"
    >>> with atomic_write(target, "w") as f:
    ...     _ = f.write("hello")
    >>> target.read_text()
    'hello'
    """
    with atomic_files([path], mode, encoding=encoding) as (f,):
        yield f


@contextmanager
def atomic_files(
    paths: Sequence[str | os.PathLike[str]], mode: str = "wb", *, encoding: str | None = None
) -> Iterator[list[IO[Any]]]:
    """Write several files all-or-nothing: each gets a temporary file, renamed only when every
    write has succeeded (a failure removes all the temporaries and leaves every target alone).

    Yields the open files in the order of ``paths``.
    """
    if mode not in _WRITE_MODES:
        raise ValueError(f"mode must be one of {_WRITE_MODES}, got {mode!r}")
    if "b" in mode and encoding is not None:
        raise ValueError("encoding is only for text modes")
    targets = [Path(p) for p in paths]
    if len(set(targets)) != len(targets):
        raise ValueError(f"duplicate targets in {[str(t) for t in targets]}")
    temps: list[str] = []
    try:
        with ExitStack() as stack:
            files: list[IO[Any]] = []
            for t in targets:
                fd, tmp = _make_temp(t)
                temps.append(tmp)
                f: IO[Any]
                if "b" in mode:
                    f = os.fdopen(fd, "wb")
                else:
                    f = os.fdopen(fd, "w", encoding=encoding or "utf-8", newline="")
                files.append(stack.enter_context(f))
            yield files
            for f in files:
                f.flush()
                os.fsync(f.fileno())
        for tmp, t in zip(temps, targets, strict=True):
            os.replace(tmp, t)
        for folder in {t.parent for t in targets}:
            _sync_folder(folder)
    except BaseException:
        for tmp in temps:
            with suppress(OSError):
                os.unlink(tmp)
        raise


def atomic_save(
    path: str | os.PathLike[str],
    writer: Callable[[IO[Any]], object],
    *,
    mode: str = "wb",
    encoding: str | None = None,
) -> Path:
    """Call ``writer(file)`` on a temporary file and move it onto ``path`` if it returns.

    Returns
    -------
    Path
        ``path``.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "x.bin"
    >>> atomic_save(p, lambda f: f.write(b"abc")).read_bytes()
    b'abc'
    """
    with atomic_write(path, mode, encoding=encoding) as f:
        writer(f)
    return Path(path)


def _sync_tree(path: Path) -> None:
    """fsync a written file, or every file below a written folder (best effort)."""
    files = [path] if path.is_file() else [Path(d) / n for d, _, ns in os.walk(path) for n in ns]
    for name in files:
        with suppress(OSError):
            fd = os.open(name, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)


@contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a fresh path, with the same name as ``path``, for a writer that wants a path.

    The writer creates a file or a folder (a ROS 2 bag) at the yielded path, which lies in a
    private temporary folder beside ``path`` (so the name, and a suffix that picks a format, are
    kept). On a clean exit it is moved onto ``path`` with ``os.replace``; whatever happens, the
    temporary folder is removed, so a failed write leaves nothing behind and ``path`` untouched.

    Raises
    ------
    FileNotFoundError
        When the writer created nothing at the yielded path.
    OSError
        When the folder does not exist or is not writable; the message names ``path``.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> target = pathlib.Path(tempfile.mkdtemp()) / "poses.csv"
    >>> with atomic_path(target) as tmp:
    ...     _ = tmp.write_text("x,y")
    ...     (tmp.name, target.exists())
    ('poses.csv', False)
    >>> target.read_text()
    'x,y'
    """
    target = Path(path)
    try:
        workdir = Path(
            tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
        )
    except OSError as exc:
        raise _naming(exc, target) from None
    try:
        tmp = workdir / target.name
        yield tmp
        if not tmp.exists():
            raise FileNotFoundError(f"cannot write {target}: the writer created no file")
        _sync_tree(tmp)
        os.replace(tmp, target)
        _sync_folder(target.parent)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
