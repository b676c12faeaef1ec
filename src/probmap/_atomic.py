"""Atomic file writes: a temporary file in the target's folder, fsync, then ``os.replace``.

A reader never sees a half-written file: either the old file (or none) or the complete new one.
If the writer raises, the temporary file is removed and the target is untouched. New files get the
mode a plain ``open(path, "w")`` gives (0o666 less the umask: 0644 under the usual umask 022).

This module is the package's one writer of output files:

- :func:`atomic_write` / :func:`atomic_save`: one file, written through an open file object;
- :func:`atomic_files`: several files, all or nothing;
- :func:`atomic_path`: one file or folder written by a library that wants a *path*
  (``savefig``, ``np.savetxt``, a ROS bag writer);
- :func:`atomic_outputs`: a command's whole set of files, all or nothing. Inside it every write
  above is *staged*: its temporary file is complete and synced, but the renames onto the targets
  happen together when the outermost ``atomic_outputs`` block ends without an error. Missing
  output folders are created when the first file is written into them; an error (or Ctrl-C)
  anywhere in the block removes every temporary file and every folder the block created, and
  leaves every target as it was.

A process killed outright (SIGKILL, a power cut) cannot remove its temporaries. They are named
``.NAME.PID-XXXXXXXX.tmp`` (a file, or a folder of :func:`atomic_path`) and
``.NAME.PID-XXXXXXXX.bak`` beside the target ``NAME``, with the writer's process id, so that the
next write of ``NAME`` removes those whose process is gone (:func:`sweep_leftovers`; the ones
of older versions, without a process id, once they are a day old). :data:`removed_leftovers`
lists what was removed, for the command line to say so.
"""

from __future__ import annotations

import errno
import os
import re
import secrets
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager, suppress
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

__all__ = [
    "OutputSet",
    "atomic_files",
    "atomic_outputs",
    "atomic_path",
    "atomic_save",
    "atomic_write",
    "removed_leftovers",
    "sweep_leftovers",
    "temporary_beside",
    "written",
]

_WRITE_MODES = ("w", "wt", "wb")

#: Temporaries of killed runs removed by :func:`sweep_leftovers` in this process, in order.
removed_leftovers: list[Path] = []
#: Every file this module put in place in this process, in order (what an interrupted
#: command wrote before it stopped).
written: list[Path] = []
_swept: set[Path] = set()  # targets whose folder was swept already (once per process)
#: Age (s) after which a temporary of an older version (no process id in its name) is stale.
LEGACY_STALE_S = 24 * 3600.0


def _temp_name(target: Path, kind: str) -> str:
    """``.NAME.PID-XXXXXXXX.KIND``: a temporary of ``target`` that names its process."""
    return f".{target.name}.{os.getpid()}-{secrets.token_hex(4)}.{kind}"


def _alive(pid: int) -> bool:
    """Whether a process ``pid`` runs on this machine (ours, or another user's)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):
        return True  # someone else's, or not ours to judge
    return True


def sweep_leftovers(path: str | os.PathLike[str]) -> list[Path]:
    """Remove the temporaries that killed runs left beside ``path`` while writing it.

    A temporary ``.NAME.PID-XXXXXXXX.tmp`` (file or folder) or ``.bak`` is removed when no
    process ``PID`` runs any more; one of an older version (``.NAME.XXXXXXXX.tmp``, no process
    id) when it is older than :data:`LEGACY_STALE_S`. A running writer's temporaries are never
    touched. Each target is swept once per process. Returns what was removed (also appended to
    :data:`removed_leftovers`); errors are ignored (a sweep never stops a write).
    """
    target = Path(path)
    key = target.absolute()
    if key in _swept:
        return []
    _swept.add(key)
    folder = target.parent if str(target.parent) else Path(".")
    name = re.escape(target.name)
    tagged = re.compile(rf"^\.{name}\.(\d+)-[0-9a-z_]{{8}}\.(tmp|bak)$")
    legacy = re.compile(rf"^\.{name}\.[0-9a-z_]{{8}}\.(tmp|bak)$")
    removed: list[Path] = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return []
    now = time.time()
    for entry in entries:
        m = tagged.match(entry.name)
        try:
            if m is not None:
                stale = not _alive(int(m.group(1)))
            elif legacy.match(entry.name) is not None:
                stale = now - entry.stat(follow_symlinks=False).st_mtime > LEGACY_STALE_S
            else:
                continue
            if not stale:
                continue
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path)
            else:
                os.unlink(entry.path)
        except OSError:
            continue
        removed.append(Path(entry.path))
    removed_leftovers.extend(removed)
    return removed


def temporary_beside(path: str | os.PathLike[str]) -> Path:
    """Create an empty temporary file beside ``path``, named as this module's temporaries
    (``.NAME.PID-XXXXXXXX.tmp``) so that a later write of ``path`` removes it if this process
    is killed; the caller removes it otherwise."""
    fd, name = _make_temp(Path(path))
    os.close(fd)
    return Path(name)


def _make_temp(path: Path) -> tuple[int, str]:
    """Create ``.NAME.PID-XXXXXXXX.tmp`` beside ``path`` (after :func:`sweep_leftovers`).

    Opened with mode 0o666 so that the process umask applies, as for a plain ``open(path, "w")``
    (``tempfile.mkstemp`` would give 0o600).
    """
    folder = path.parent
    sweep_leftovers(path)
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    for _ in range(100):
        tmp = folder / _temp_name(path, "tmp")
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


def _named(exc: BaseException, targets: Sequence[Path]) -> BaseException:
    """An ``OSError`` raised by a writer that does not say which output it was writing (a full
    disk, a failing device): the same kind of error naming the targets; anything else as is."""
    if not isinstance(exc, OSError) or not targets:
        return exc
    text = str(exc)
    if any(str(t) in text or t.name in text for t in targets):
        return exc
    names = ", ".join(str(t) for t in targets)
    reason = exc.strerror or text or type(exc).__name__
    try:
        return type(exc)(exc.errno, f"cannot write {names}: {reason}", str(targets[0]))
    except TypeError:  # pragma: no cover - an OSError subclass with another signature
        return exc


# ----------------------------------------------------------------------------- output sets
@dataclass(eq=False)
class _Staged:
    tmp: Path  # the complete temporary file (or folder)
    target: Path
    workdir: Path | None = None  # atomic_path's private folder, removed afterwards


@dataclass(eq=False)
class OutputSet:
    """The files staged by one :func:`atomic_outputs` block (read-only for callers)."""

    staged: dict[Path, _Staged] = field(default_factory=dict)
    created: list[Path] = field(default_factory=list)
    create_folders: bool = True

    @property
    def targets(self) -> list[Path]:
        """The files that the block will write, in the order they were staged."""
        return list(self.staged)

    def folder(self, path: str | os.PathLike[str]) -> Path:
        """Create the folder ``path`` and its missing parents now (mode 0o777 less the umask);
        the ones created are removed again if the block fails. Returns ``path``."""
        return _make_folder(Path(path), self)

    def _stage(self, item: _Staged) -> None:
        old = self.staged.pop(item.target, None)
        if old is not None:  # written twice in one block: the last write wins, as without one
            _discard(old)
        self.staged[item.target] = item


_ACTIVE: ContextVar[OutputSet | None] = ContextVar("probmap_atomic_outputs", default=None)


def _make_folder(folder: Path, outputs: OutputSet | None) -> Path:
    """Create ``folder`` and its missing parents, recording them in ``outputs``."""
    missing: list[Path] = []
    p = folder
    while not p.exists() and not p.is_symlink():
        missing.append(p)
        if p.parent == p:  # pragma: no cover - a missing root
            break
        p = p.parent
    if not p.is_dir():
        raise NotADirectoryError(
            errno.ENOTDIR, f"cannot create output folder {folder}: {p} is not a folder", str(p)
        )
    for d in reversed(missing):
        try:
            os.mkdir(d)
        except FileExistsError:
            if not d.is_dir():
                raise
            continue
        except OSError as exc:
            reason = exc.strerror or str(exc)
            raise type(exc)(
                exc.errno, f"cannot create output folder {d}: {reason}", str(d)
            ) from None
        if outputs is not None:
            outputs.created.append(d)
    return folder


def _discard(item: _Staged) -> None:
    if item.workdir is not None:
        shutil.rmtree(item.workdir, ignore_errors=True)
    else:
        with suppress(OSError):
            os.unlink(item.tmp)


def _remove_created(outputs: OutputSet) -> None:
    for d in reversed(outputs.created):
        with suppress(OSError):
            os.rmdir(d)  # only when empty: never a file that was there before


def _backup(target: Path) -> Path | None:
    """A hard link to an existing ``target``, so that a failed commit can put it back."""
    for _ in range(10):
        bak = target.parent / _temp_name(target, "bak")
        try:
            os.link(target, bak)
            return bak
        except FileExistsError:  # pragma: no cover
            continue
        except OSError:  # no hard links here: the old file cannot be kept
            return None
    return None  # pragma: no cover


def _commit(outputs: OutputSet) -> None:
    """Move every staged file onto its target; on a failure put back what was there before."""
    items = list(outputs.staged.values())
    for it in items:
        if it.target.is_dir() and not it.tmp.is_dir():
            raise IsADirectoryError(
                errno.EISDIR, f"cannot write {it.target}: a folder of that name exists",
                str(it.target),
            )  # fmt: skip
    done: list[tuple[Path, Path | None, bool]] = []
    try:
        for it in items:
            existed = it.target.exists() or it.target.is_symlink()
            backup = _backup(it.target) if existed and not it.target.is_dir() else None
            try:
                os.replace(it.tmp, it.target)
            except BaseException:
                if backup is not None:
                    with suppress(OSError):
                        os.unlink(backup)
                raise
            done.append((it.target, backup, existed))
    except BaseException:
        for target, backup, existed in reversed(done):
            with suppress(OSError):
                if backup is not None:
                    os.replace(backup, target)
                elif not existed:
                    if target.is_dir() and not target.is_symlink():
                        shutil.rmtree(target, ignore_errors=True)
                    else:
                        os.unlink(target)
        raise
    finally:
        for it in items:
            if it.workdir is not None:
                shutil.rmtree(it.workdir, ignore_errors=True)
    written.extend(target for target, _, _ in done)
    for _, backup, _ in done:
        if backup is not None:
            with suppress(OSError):
                os.unlink(backup)
    for folder in {it.target.parent for it in items}:
        _sync_folder(folder)


@contextmanager
def atomic_outputs(*, create_folders: bool = True) -> Iterator[OutputSet]:
    """All-or-nothing for a set of output files written by any of this module's writers.

    Every :func:`atomic_files`, :func:`atomic_write`, :func:`atomic_save` and
    :func:`atomic_path` inside the block (in this thread or task, at any depth of calls) writes
    its complete temporary file and *stages* it; when the block ends without an error the staged
    files are renamed onto their targets, one after the other. Missing output folders are
    created as files are written into them (:meth:`OutputSet.folder` creates one explicitly).

    If anything raises inside the block -- a writer, the work between two writes, Ctrl-C
    (``KeyboardInterrupt``) -- or a rename fails, the temporary files and the folders the block
    created are removed, and targets already renamed are put back as they were (a file that did
    not exist is removed, one that did is restored from a hard link where the file system has
    them). A nested block joins the outer one: the outermost block commits, and its
    ``create_folders`` applies (``False``: a missing folder is an error, as outside a block).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "run"
    >>> with atomic_outputs():
    ...     _ = atomic_save(out / "a.txt", lambda f: f.write(b"a"))
    ...     (out / "a.txt").exists()
    False
    >>> sorted(p.name for p in out.iterdir())
    ['a.txt']
    """
    active = _ACTIVE.get()
    if active is not None:
        yield active
        return
    outputs = OutputSet(create_folders=create_folders)
    token = _ACTIVE.set(outputs)
    try:
        try:
            yield outputs
        finally:
            _ACTIVE.reset(token)
        _commit(outputs)
    except BaseException:
        for item in outputs.staged.values():
            _discard(item)
        _remove_created(outputs)
        raise


def _sync_folder(folder: Path) -> None:
    """Make the rename durable (POSIX); best effort where folders cannot be opened."""
    if os.name != "posix":  # pragma: no cover
        return
    _fsync_name(folder)


def _fsync_name(name: str | os.PathLike[str]) -> None:
    """fsync the file or folder ``name`` through a read-only descriptor; errors are ignored
    (best effort: some file systems cannot open or sync a folder)."""
    with suppress(OSError):
        fd = os.open(name, os.O_RDONLY)
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
    outputs = _ACTIVE.get()
    temps: list[str] = []
    try:
        with ExitStack() as stack:
            files: list[IO[Any]] = []
            for t in targets:
                if outputs is not None and outputs.create_folders:
                    _make_folder(t.parent if str(t.parent) else Path("."), outputs)
                fd, tmp = _make_temp(t)
                temps.append(tmp)
                f: IO[Any]
                if "b" in mode:
                    f = os.fdopen(fd, "wb")
                else:
                    f = os.fdopen(fd, "w", encoding=encoding or "utf-8", newline="")
                files.append(stack.enter_context(f))
            try:
                yield files
                for f in files:
                    f.flush()
                    os.fsync(f.fileno())
            except BaseException as exc:
                named = _named(exc, targets)
                if named is exc:
                    raise
                raise named from None
        if outputs is not None:
            for tmp, t in zip(temps, targets, strict=True):
                outputs._stage(_Staged(Path(tmp), t))
            return
        for tmp, t in zip(temps, targets, strict=True):
            os.replace(tmp, t)
            written.append(t)
        for folder in {t.parent for t in targets}:
            _sync_folder(folder)
    except BaseException as exc:
        for tmp in temps:
            if outputs is None or Path(tmp) not in {i.tmp for i in outputs.staged.values()}:
                with suppress(OSError):
                    os.unlink(tmp)
        # closing a file whose flush failed (a full disk) raises again, unnamed, over the
        # named error: name it here too
        named = _named(exc, targets)
        if named is exc:
            raise
        raise named from None


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
        _fsync_name(name)


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
        As :func:`atomic_write`.

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
    outputs = _ACTIVE.get()
    if outputs is not None and outputs.create_folders:
        _make_folder(target.parent if str(target.parent) else Path("."), outputs)
    sweep_leftovers(target)
    try:
        workdir = Path(
            tempfile.mkdtemp(
                prefix=f".{target.name}.{os.getpid()}-", suffix=".tmp", dir=target.parent
            )
        )
    except OSError as exc:
        raise _naming(exc, target) from None
    staged = False
    try:
        tmp = workdir / target.name
        try:
            yield tmp
        except BaseException as exc:
            named = _named(exc, [target])
            if named is exc:
                raise
            raise named from None
        if not tmp.exists():
            raise FileNotFoundError(f"cannot write {target}: the writer created no file")
        _sync_tree(tmp)
        if outputs is not None:
            outputs._stage(_Staged(tmp, target, workdir))
            staged = True
            return
        os.replace(tmp, target)
        written.append(target)
        _sync_folder(target.parent)
    finally:
        if not staged:
            shutil.rmtree(workdir, ignore_errors=True)
