"""Saved runs of submap graph SLAM (``probmap slam grid --save-session`` / ``--resume``).

The algorithm (:class:`~probmap.slam.laser.submap_slam.SubmapSlam`) keeps its state in memory
and opens no files; this module writes that state to a file and reads it back, so that a run
continues where it stopped: feeding the rest of a log to the loaded object gives exactly what
one run over the whole log gives (a tested property).
"""

from __future__ import annotations

import os
from pathlib import Path

from probmap.slam.laser.submap_slam import SubmapSlam

__all__ = ["SESSION_FORMAT", "SESSION_VERSION", "load_session", "save_session"]

#: Header of a saved session.
SESSION_FORMAT = "probmap.GraphSlam session"
SESSION_VERSION = 1


def save_session(slam: SubmapSlam, path: str | os.PathLike[str]) -> Path:
    """Write the whole state of ``slam`` (pose graph, submaps, stored scans, settings) to
    ``path``, so that :func:`load_session` continues the run where it stopped. Save before
    :meth:`~probmap.slam.laser.submap_slam.SubmapSlam.finish` (which ends the run).

    The file is a Python pickle with a header (format, version, probmap version), written
    atomically. Like any pickle it can run code when loaded: load only sessions you wrote.
    The cached match fields and max-grids are not saved (they are rebuilt on demand).

    Raises
    ------
    RuntimeError
        After ``finish()``.
    """
    import pickle

    from probmap import __version__
    from probmap._atomic import atomic_write

    if slam.finished:
        raise RuntimeError("finish() was called: save the session before finishing the run")
    payload = {
        "format": SESSION_FORMAT,
        "version": SESSION_VERSION,
        "probmap": __version__,
        "state": slam,
    }
    p = Path(path)
    with atomic_write(p, "wb") as f:
        pickle.dump(payload, f, protocol=pickle.HIGHEST_PROTOCOL)
    return p


def load_session(path: str | os.PathLike[str]) -> SubmapSlam:
    """A run saved by :func:`save_session`, ready for more scans (same settings).

    Raises
    ------
    ValueError
        When the file is not a probmap graph-SLAM session, or one of another format
        version; the message names the file.
    FileNotFoundError
        When it does not exist.
    """
    import pickle

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such session file")
    try:
        with open(p, "rb") as f:
            payload = pickle.load(f)
    except (pickle.UnpicklingError, EOFError, AttributeError, ImportError, IndexError) as exc:
        raise ValueError(f"{p}: not a probmap graph-SLAM session ({exc})") from None
    if not isinstance(payload, dict) or payload.get("format") != SESSION_FORMAT:
        raise ValueError(f"{p}: not a probmap graph-SLAM session")
    if payload.get("version") != SESSION_VERSION:
        raise ValueError(
            f"{p}: session format version {payload.get('version')}, this probmap reads "
            f"version {SESSION_VERSION} (written by probmap {payload.get('probmap')})"
        )
    state = payload.get("state")
    if not isinstance(state, SubmapSlam):
        raise ValueError(f"{p}: the session holds no SubmapSlam")
    return state
