"""Saved runs of submap graph SLAM (``probmap slam grid --save-session`` / ``--resume``).

The algorithm (:class:`~probmap.slam.laser.submap_slam.SubmapSlam`) keeps its state in memory
and opens no files; this module writes that state to a file and reads it back, so that a run
continues where it stopped: feeding the rest of a log to the loaded object gives exactly what
one run over the whole log gives (a tested property).

A session is data, never code (docs/sessions.md has the layout): a zip archive, like numpy's
``.npz``, of uncompressed members

- ``header.json``: format name and version, the probmap version, the configuration, which
  scans the session covers (count, first and last timestamp, the log they came from with a
  SHA-256 fingerprint of its timestamps and odometry) and whether the run that saved it
  reached the end of its log;
- ``state.json``: the run's objects as a tree of plain JSON values, each object named by one
  of a fixed list of probmap classes, each array by the member that holds it;
- ``arrays/NAME.npy``: the arrays, read with ``allow_pickle=False``.

Reading checks the archive and the header before it reads anything else, builds only the
listed classes (without running their code beyond the frozen configurations' checks) and
checks the state's consistency before it returns; a file that is not a session, a session of
another version and an old pickled session are one-line errors naming the file. The cached
match fields and max-grids of finished submaps are not saved (they are rebuilt on demand).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import warnings
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from probmap.datasets.records import ScanBatch
from probmap.pipelines._session_state import (
    ARRAY_KINDS,
    Decoder,
    Encoder,
    StateError,
    check_state,
)
from probmap.slam.laser.submap_slam import SubmapSlam

__all__ = [
    "SESSION_FORMAT",
    "SESSION_VERSION",
    "NotASessionError",
    "SessionGapWarning",
    "SessionInfo",
    "SessionLog",
    "batch_fingerprint",
    "check_continuation",
    "load_session",
    "read_session_info",
    "resume_batch",
    "save_session",
]

#: Header of a saved session.
SESSION_FORMAT = "probmap.GraphSlam session"
#: Version 1 was a Python pickle (refused: it could run code); 2 the archive of arrays; 3 the
#: same archive, with the pairwise closure check's state and settings (a version-2 session
#: would resume a different algorithm: refused); 4 adds lidar-only SLAM's recent steps (its
#: motion model); 5 the odometry's measured turn errors (``local.recover_turn``).
SESSION_VERSION = 5

_HEADER = "header.json"
_STATE = "state.json"
_ARRAYS = "arrays/"
_ZIP_MAGIC = b"PK\x03\x04"
_PICKLE_MAGIC = b"\x80"  # a pickle of protocol 2 or newer starts with the PROTO opcode
_MAX_HEADER_BYTES = 1 << 20
_NOT_A_SESSION = "not a probmap graph-SLAM session"


class NotASessionError(ValueError):
    """The file is no probmap graph-SLAM session at all (not a malformed one, nor one of
    another version)."""


class SessionGapWarning(UserWarning):
    """A resumed session's run stopped before the end of its log, and the new log does not
    continue that log: the scans between them are missing from the result."""


@dataclass(frozen=True)
class SessionInfo:
    """What a session's header says about the scans it covers.

    Attributes
    ----------
    path : Path
        The session file.
    probmap : str
        The probmap version that wrote it.
    scans : int
        Scans in the session (every log it was built from).
    first_time, last_time : float or None
        Timestamps (s) of its first and last scan; None without scans.
    complete : bool
        Whether the run that saved it read its log to the end (False: stopped early, e.g. by
        Ctrl-C, so the rest of that log is not in the session).
    log_name : str or None
        File name of the log of its last run (None when saved outside ``slam grid``).
    log_scans : int or None
        Scans of that log as read.
    log_used : int or None
        Scans of that log in the session (``log_scans`` when ``complete``).
    log_sha256 : str or None
        :func:`batch_fingerprint` of that log.
    """

    path: Path
    probmap: str
    scans: int
    first_time: float | None
    last_time: float | None
    complete: bool
    log_name: str | None = None
    log_scans: int | None = None
    log_used: int | None = None
    log_sha256: str | None = None


@dataclass(frozen=True)
class SessionLog:
    """The log a run reads, as a session's header records it.

    Attributes
    ----------
    name : str
        Its file name.
    scans : int
        Its scans as read (those a resumed session held already included).
    sha256 : str
        :func:`batch_fingerprint` of its scans.
    """

    name: str
    scans: int
    sha256: str

    @classmethod
    def of(cls, path: str | os.PathLike[str], batch: ScanBatch) -> SessionLog:
        """The record of the log at ``path`` read as ``batch``."""
        return cls(Path(path).name, len(batch.times), batch_fingerprint(batch))


def batch_fingerprint(batch: ScanBatch) -> str:
    """SHA-256 (hex) of a scan batch's timestamps and sensor odometry (float64, C order): a
    cheap fingerprint of a log as read, recorded in a session's header."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(batch.times, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(batch.laser_poses, dtype=np.float64).tobytes())
    return h.hexdigest()


# ----------------------------------------------------------------------------- files
def _plain_config(cfg: Any) -> Any:
    from probmap.config import _plain

    return _plain(cfg)


def _member(name: str) -> zipfile.ZipInfo:
    """A stored member with a fixed date: the same state gives the same bytes."""
    info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
    info.compress_type = zipfile.ZIP_STORED
    return info


def save_session(
    slam: SubmapSlam,
    path: str | os.PathLike[str],
    *,
    complete: bool = True,
    log: SessionLog | None = None,
    log_used: int | None = None,
) -> Path:
    """Write the whole state of ``slam`` (pose graph, submaps, stored scans, settings) to
    ``path``, so that :func:`load_session` continues the run where it stopped. Save before
    :meth:`~probmap.slam.laser.submap_slam.SubmapSlam.finish` (which ends the run).

    The file is written next to ``path`` and renamed over it once complete (an interrupted
    save leaves ``path`` as it was). Its layout is in the module docstring and
    docs/sessions.md.

    Parameters
    ----------
    slam : SubmapSlam
        The run, not finished.
    path : path-like
        The session file.
    complete : bool
        Whether the run read its log to the end (False after a stop: a resume with the same
        log continues after the session's last scan).
    log : SessionLog, optional
        The log of this run (recorded in the header; see :class:`SessionInfo`).
    log_used : int, optional
        How many of its scans the session holds (all of them when ``complete``).

    Raises
    ------
    RuntimeError
        After ``finish()``.
    TypeError
        When the state holds a value sessions cannot store (names the attribute).
    """
    from probmap import __version__
    from probmap._atomic import atomic_write

    if slam.finished:
        raise RuntimeError("finish() was called: save the session before finishing the run")
    enc = Encoder()
    tree = enc.encode(slam, "SubmapSlam")
    times = slam.scan_times
    header = {
        "format": SESSION_FORMAT,
        "version": SESSION_VERSION,
        "probmap": __version__,
        "scans": {
            "count": len(times),
            "first_time": float(times[0]) if times else None,
            "last_time": float(times[-1]) if times else None,
            "nodes": slam.nodes,
            "submaps": len(slam.submaps),
        },
        "complete": bool(complete),
        "log": None
        if log is None
        else {
            "name": log.name,
            "scans": log.scans,
            "used": log.scans if log_used is None else log_used,
            "sha256": log.sha256,
        },
        "max_range": slam.max_range,
        "config": _plain_config(slam.config),
    }
    p = Path(path)
    with atomic_write(p, "wb") as f, zipfile.ZipFile(f, "w", zipfile.ZIP_STORED) as z:
        z.writestr(_member(_HEADER), json.dumps(header, indent=1, allow_nan=False))
        z.writestr(_member(_STATE), json.dumps(tree, separators=(",", ":"), allow_nan=False))
        for key, a in enc.arrays.items():
            with z.open(_member(f"{_ARRAYS}{key}.npy"), "w", force_zip64=True) as member:
                np.lib.format.write_array(member, a, allow_pickle=False)
    return p


def _open(p: Path) -> zipfile.ZipFile:
    """The session archive, after the checks that need nothing of its content: it exists, is
    no pickle, is a zip of uncompressed members holding a header."""
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such session file")
    with open(p, "rb") as f:
        magic = f.read(4)
    if magic[:1] == _PICKLE_MAGIC:
        raise ValueError(
            f"{p}: a Python pickle, never loaded (sessions of older probmap versions were "
            "pickles, which can run code): re-run probmap slam grid --save-session to make a "
            "new one"
        )
    if magic != _ZIP_MAGIC:
        raise NotASessionError(f"{p}: {_NOT_A_SESSION}")
    try:
        z = zipfile.ZipFile(p)
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise NotASessionError(f"{p}: {_NOT_A_SESSION} ({exc})") from None
    infos = {i.filename: i for i in z.infolist()}
    bad = [n for n, i in infos.items() if i.compress_type != zipfile.ZIP_STORED]
    if _HEADER not in infos or _STATE not in infos or bad:
        z.close()
        raise NotASessionError(f"{p}: {_NOT_A_SESSION}")
    return z


def _read_header(p: Path, z: zipfile.ZipFile) -> dict[str, Any]:
    info = z.getinfo(_HEADER)
    if info.file_size > _MAX_HEADER_BYTES:
        raise ValueError(f"{p}: {_NOT_A_SESSION} (a header of {info.file_size} bytes)")
    try:
        header = json.loads(z.read(_HEADER).decode("utf-8"))
    except (ValueError, UnicodeDecodeError, RecursionError, zipfile.BadZipFile, OSError):
        raise NotASessionError(f"{p}: {_NOT_A_SESSION} (its header is not JSON)") from None
    if not isinstance(header, dict) or header.get("format") != SESSION_FORMAT:
        raise NotASessionError(f"{p}: {_NOT_A_SESSION}")
    if header.get("version") != SESSION_VERSION:
        raise ValueError(
            f"{p}: session format version {header.get('version')}, this probmap reads "
            f"version {SESSION_VERSION} (written by probmap {header.get('probmap')})"
        )
    return header


def _info_of(p: Path, header: dict[str, Any]) -> SessionInfo:
    """The :class:`SessionInfo` of a checked header (its fields checked here)."""
    scans = header.get("scans")
    log = header.get("log")
    try:
        if not isinstance(scans, dict) or not (log is None or isinstance(log, dict)):
            raise TypeError
        count = scans["count"]
        first, last = scans["first_time"], scans["last_time"]
        complete = header["complete"]
        if type(count) is not int or count < 0 or type(complete) is not bool:
            raise TypeError
        for t in (first, last):
            if t is not None and not isinstance(t, (int, float)):
                raise TypeError
        log = log or {}
        name, n, used, sha = (log.get(k) for k in ("name", "scans", "used", "sha256"))
        if not all(x is None or isinstance(x, str) for x in (name, sha)):
            raise TypeError
        if not all(x is None or type(x) is int for x in (n, used)):
            raise TypeError
    except (KeyError, TypeError):
        raise ValueError(f"{p}: a malformed session header (scans, complete or log)") from None
    return SessionInfo(
        p, str(header.get("probmap")), count,
        None if first is None else float(first), None if last is None else float(last),
        complete, name, n, used, sha,
    )  # fmt: skip


def read_session_info(path: str | os.PathLike[str]) -> SessionInfo:
    """What a session covers, from its header alone (its arrays are not read).

    Raises
    ------
    ValueError
        When the file is not a session of this format version (one line naming it).
    FileNotFoundError
        When it does not exist.
    """
    p = Path(path)
    with _open(p) as z:
        return _info_of(p, _read_header(p, z))


def _array_reader(p: Path, z: zipfile.ZipFile) -> Callable[[str], NDArray[Any]]:
    """``read(key)``: the array ``arrays/KEY.npy`` of the archive, after checking that the
    size its header declares is the member's size (a crafted header cannot make it allocate
    more than the file holds)."""
    infos = {i.filename: i for i in z.infolist()}

    def read(key: str) -> NDArray[Any]:
        info = infos.get(f"{_ARRAYS}{key}.npy")
        if info is None:
            raise StateError(f"no array {key!r}")
        with z.open(info) as f:
            try:
                version = np.lib.format.read_magic(f)
                if version == (1, 0):
                    shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
                elif version == (2, 0):
                    shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
                else:
                    raise ValueError(f"npy format version {version}")
            except (ValueError, OSError, EOFError, SyntaxError) as exc:
                raise StateError(f"array {key}: {exc}") from None
            if dtype.hasobject or dtype.kind not in ARRAY_KINDS or fortran:
                raise StateError(f"array {key} of dtype {dtype}")
            count = math.prod(shape)
            if f.tell() + count * dtype.itemsize != info.file_size:
                raise StateError(f"array {key}: its header does not match its size")
            data = f.read(count * dtype.itemsize)
        return np.frombuffer(data, dtype=dtype).reshape(shape).copy()

    return read


def load_session(path: str | os.PathLike[str]) -> SubmapSlam:
    """A run saved by :func:`save_session`, ready for more scans (same settings).

    The archive and its header are checked before anything else is read; the state is
    built only from the classes sessions hold and checked before it is returned.

    Raises
    ------
    NotASessionError
        When the file is not a probmap graph-SLAM session (a ValueError; one line naming
        the file).
    ValueError
        When it is one of another format version (an old pickled session among them:
        re-run) or a malformed one; one line naming the file.
    FileNotFoundError
        When it does not exist.
    """
    p = Path(path)
    with _open(p) as z:
        _info_of(p, _read_header(p, z))
        try:
            if z.getinfo(_STATE).file_size > max(p.stat().st_size, 0):
                raise StateError("a state larger than the file")
            tree = json.loads(z.read(_STATE).decode("utf-8"))
            dec = Decoder(_array_reader(p, z))
            slam = dec.decode(tree)
            check_state(slam, dec.built)
        except StateError as exc:
            raise ValueError(f"{p}: a malformed probmap session ({exc})") from None
        except (ValueError, UnicodeDecodeError, RecursionError, zipfile.BadZipFile) as exc:
            raise ValueError(f"{p}: a malformed probmap session ({exc})") from None
        except (TypeError, AttributeError, IndexError, KeyError, OverflowError) as exc:
            # what the checks above missed, met while checking the state: still one line
            what = f"{type(exc).__name__}: {exc}"
            raise ValueError(f"{p}: a malformed probmap session ({what})") from None
    return slam


# ----------------------------------------------------------------------------- resuming
def check_continuation(
    slam: SubmapSlam,
    batch: ScanBatch,
    info: SessionInfo | None = None,
    *,
    log_name: str = "the log",
) -> int:
    """How many of ``batch``'s first scans the session ``slam`` holds already; resuming feeds
    the scans after them.

    A log continues a session when its scans come after the session's last scan, or when its
    scans up to that time are the session's own last scans, the same timestamps and odometry
    (the log the session was saved from, as after an interrupted run: those scans are skipped,
    so that nothing is duplicated).

    Raises
    ------
    ValueError
        When the log overlaps the session with other scans (it would duplicate or reorder
        them), or adds no scan after the session's last.

    Warns
    -----
    SessionGapWarning
        When the session's run stopped before the end of its log (``info.complete`` False)
        and ``batch`` is not that log: the rest of that log is missing.
    """
    where = f"{info.path}: " if info is not None else ""
    s = len(slam.scan_times)
    times = np.asarray(batch.times, dtype=np.float64)
    if s == 0:
        return 0
    last = slam.scan_times[-1]
    k = int(np.searchsorted(times, last, side="right")) if times.size else 0
    if k and not (np.all(np.diff(times[: k + 1]) >= 0)):
        k = int(np.count_nonzero(times <= last))
    if k:
        # the log's scans up to the session's last must be the session's own, from where the
        # log starts in it: the same timestamps and odometry
        held = np.asarray(slam.scan_times, dtype=np.float64)
        at = int(np.searchsorted(held, times[0], side="left"))
        span = slice(at, at + k)
        same = (
            at + k <= s
            and np.array_equal(held[span], times[:k])
            and np.array_equal(
                np.asarray(slam.scan_odometry[span], dtype=np.float64).reshape(-1, 3),
                np.asarray(batch.laser_poses[:k], dtype=np.float64),
            )
        )
        if same and k == times.size:
            raise ValueError(
                f"{where}the session holds every scan of {log_name} already (up to "
                f"t = {last:.3f} s): nothing to resume"
            )
        if not same or at + k != s:
            raise ValueError(
                f"{where}{log_name} starts at t = {times[0]:.3f} s, before the session's last "
                f"scan at t = {last:.3f} s, with other scans: resume with the log that "
                "continues the session"
            )
        return k
    if info is not None and not info.complete:
        left = ""
        if info.log_scans is not None and info.log_used is not None:
            left = f", {info.log_scans - info.log_used:,} scans"
        warnings.warn(
            f"{where}its run stopped at t = {last:.3f} s{left} before the end of its log "
            f"{info.log_name or ''}; {log_name} starts at t = {times[0]:.3f} s: the scans "
            "between are missing from the result",
            SessionGapWarning,
            stacklevel=2,
        )
    return 0


def resume_batch(
    slam: SubmapSlam, batch: ScanBatch, info: SessionInfo | None = None, *, log_name: str
) -> tuple[ScanBatch, int]:
    """``batch`` without the first scans the session ``slam`` holds already
    (:func:`check_continuation`), and how many were dropped."""
    k = check_continuation(slam, batch, info, log_name=log_name)
    if k == 0:
        return batch, 0
    return batch.rows(slice(k, None)), k
