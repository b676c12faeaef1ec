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

import dataclasses
import hashlib
import json
import math
import os
import warnings
import zipfile
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from probmap.datasets.records import ScanBatch
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
#: Version 1 was a Python pickle (refused: it could run code); 2 is the archive of arrays.
SESSION_VERSION = 2

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


# ----------------------------------------------------------------------------- the codec
class _Bad(Exception):
    """A malformed session (the message says what); becomes one ValueError naming the file."""


def _object_classes() -> dict[str, type]:
    """The classes whose instances a session holds as their attributes (never their code)."""
    from probmap.grid.occupancy import OccupancyGrid
    from probmap.slam.laser.closures import LoopClosing
    from probmap.slam.laser.submaps import Submap
    from probmap.slam.posegraph.optimize import PoseGraph2D

    return {c.__name__: c for c in (SubmapSlam, LoopClosing, Submap, PoseGraph2D, OccupancyGrid)}


def _value_classes() -> dict[str, type]:
    """The frozen dataclasses a session holds by their fields (built through their checks)."""
    from probmap.grid.occupancy import InverseSensorModel
    from probmap.grid.spec import GridSpec
    from probmap.slam.laser.closures import ClosureConfig, LoopClosure
    from probmap.slam.laser.scan_matching import MatcherConfig, MatchField
    from probmap.slam.laser.submap_slam import (
        LocalMatchingConfig,
        OptimizationConfig,
        SubmapConfig,
        SubmapSlamConfig,
    )
    from probmap.slam.posegraph.optimize import OptimizerConfig

    classes = (
        SubmapSlamConfig, LocalMatchingConfig, SubmapConfig, OptimizationConfig, ClosureConfig,
        MatcherConfig, OptimizerConfig, InverseSensorModel, GridSpec, MatchField, LoopClosure,
    )  # fmt: skip
    return {c.__name__: c for c in classes}


#: Attributes not saved: caches rebuilt on demand, with the value a loaded object starts with.
_TRANSIENT: dict[str, dict[str, Callable[[], Any]]] = {
    "LoopClosing": {"_cache": OrderedDict},
    "PoseGraph2D": {"_system": lambda: None, "_system_key": lambda: (-1, -1)},
    "OccupancyGrid": {"_fast": lambda: None},
}
#: Bound methods a saved object may hold: (class of the object bound to, method name).
_METHODS = {("SubmapSlam", "_full_points")}
_NUMPY_SCALARS = ("bool", "int64", "int32", "float64", "float32")
_ARRAY_KINDS = "biuf"  # bool, signed and unsigned integers, floats: never objects


class _Encoder:
    """Turns a :class:`SubmapSlam` into a JSON tree and a dict of arrays."""

    def __init__(self) -> None:
        self.arrays: dict[str, NDArray[Any]] = {}
        self._memo: dict[int, int] = {}  # id(object) -> reference number
        self._keep: list[Any] = []  # keeps every memoized object alive (ids stay unique)
        self.objects = _object_classes()
        self.values = _value_classes()

    def _array(self, a: NDArray[Any], where: str) -> str:
        if a.dtype.kind not in _ARRAY_KINDS:
            raise TypeError(f"cannot save {where}: an array of dtype {a.dtype}")
        key = f"a{len(self.arrays)}"
        self.arrays[key] = np.ascontiguousarray(a)
        return key

    def _ref(self, obj: Any) -> int | None:
        return self._memo.get(id(obj))

    def _remember(self, obj: Any) -> int:
        n = len(self._memo)
        self._memo[id(obj)] = n
        self._keep.append(obj)
        return n

    def encode(self, v: Any, where: str) -> Any:
        """The JSON node of ``v`` (``where`` names it in errors)."""
        if v is None or isinstance(v, (bool, str)):
            return v
        if isinstance(v, np.generic):
            name = v.dtype.name
            if name not in _NUMPY_SCALARS:
                raise TypeError(f"cannot save {where}: a numpy {name}")
            return {"t": "np", "dtype": name, "v": self.encode(v.item(), where)}
        if isinstance(v, int):
            return v
        if isinstance(v, float):
            return v if math.isfinite(v) else {"t": "float", "v": repr(v)}
        if isinstance(v, np.ndarray):
            n = self._ref(v)
            if n is not None:
                return {"t": "ref", "id": n}
            return {"t": "array", "key": self._array(v, where), "id": self._remember(v)}
        if isinstance(v, tuple):
            return {"t": "tuple", "items": [self.encode(x, where) for x in v]}
        if isinstance(v, (set, frozenset)):
            return {"t": "set", "items": [self.encode(x, where) for x in v]}
        if type(v) is dict:
            return {
                "t": "dict",
                "keys": [self.encode(k, where) for k in v],
                "values": [self.encode(x, where) for x in v.values()],
            }
        if type(v) is list:
            n = self._ref(v)
            if n is not None:  # a list two objects share (the run's submaps, its travel)
                return {"t": "ref", "id": n}
            return self._list(v, where)
        name = type(v).__name__
        if dataclasses.is_dataclass(v) and self.values.get(name) is type(v):
            fields = {
                f.name: self.encode(getattr(v, f.name), f"{where}.{f.name}")
                for f in dataclasses.fields(v)
                if f.init
            }
            return {"t": "value", "class": name, "fields": fields}
        if self.objects.get(name) is type(v):
            n = self._ref(v)
            if n is not None:
                return {"t": "ref", "id": n}
            n = self._remember(v)
            transient = _TRANSIENT.get(name, {})
            attrs = {
                k: self.encode(x, f"{name}.{k}") for k, x in vars(v).items() if k not in transient
            }
            return {"t": "object", "class": name, "id": n, "attrs": attrs}
        owner = getattr(v, "__self__", None)
        method = getattr(v, "__name__", None)
        if owner is not None and (type(owner).__name__, method) in _METHODS:
            return {"t": "method", "of": self.encode(owner, where), "name": method}
        raise TypeError(f"cannot save {where}: a {type(v).__name__}")

    def _list(self, v: list[Any], where: str) -> Any:
        """A list; long lists of one kind are packed into one array (Python floats, Python
        ints, or arrays of one dtype and trailing shape, each kept once when repeated)."""
        n = self._remember(v)
        if v and all(type(x) is float for x in v):
            return {"t": "floats", "key": self._array(np.asarray(v, dtype=np.float64), where),
                    "id": n}  # fmt: skip
        if v and all(type(x) is int for x in v) and -(2**63) <= min(v) and max(v) < 2**63:
            return {"t": "ints", "key": self._array(np.asarray(v, dtype=np.int64), where),
                    "id": n}  # fmt: skip
        first = v[0] if v else None
        if (
            isinstance(first, np.ndarray)
            and first.ndim >= 1
            and all(
                isinstance(x, np.ndarray)
                and x.dtype == first.dtype
                and x.ndim == first.ndim
                and x.shape[1:] == first.shape[1:]
                for x in v
            )
        ):
            unique: dict[int, int] = {}
            index = np.empty(len(v), dtype=np.int64)
            parts: list[NDArray[Any]] = []
            for i, x in enumerate(v):
                j = unique.setdefault(id(x), len(unique))
                if j == len(parts):
                    parts.append(x)
                index[i] = j
            lengths = np.asarray([p.shape[0] for p in parts], dtype=np.int64)
            return {
                "t": "arrays",
                "id": n,
                "data": self._array(np.concatenate(parts, axis=0), where),
                "lengths": self._array(lengths, where),
                "index": self._array(index, where),
            }
        return {"t": "list", "id": n, "items": [self.encode(x, where) for x in v]}


class _Decoder:
    """Builds the objects of a JSON tree from :class:`_Encoder`, reading arrays on demand."""

    def __init__(self, read_array: Callable[[str], NDArray[Any]]) -> None:
        self._read = read_array
        self._memo: dict[int, Any] = {}
        self.objects = _object_classes()
        self.values = _value_classes()
        self.built: list[Any] = []  # every object built, for the consistency checks

    def _remember(self, node: dict[str, Any], obj: Any) -> None:
        n = node.get("id")
        if type(n) is not int or n in self._memo:
            raise _Bad("a malformed reference number")
        self._memo[n] = obj

    def _key(self, node: dict[str, Any], name: str = "key") -> NDArray[Any]:
        key = node.get(name)
        if not isinstance(key, str):
            raise _Bad("an array without a name")
        return self._read(key)

    def decode(self, node: Any) -> Any:
        if node is None or isinstance(node, (bool, int, str)):
            return node
        if isinstance(node, float):
            return node
        if not isinstance(node, dict):
            raise _Bad(f"an unexpected {type(node).__name__} in the state")
        t = node.get("t")
        if t == "float":
            v = node.get("v")
            if v not in ("nan", "inf", "-inf"):
                raise _Bad(f"a malformed number {v!r}")
            return float(v)
        if t == "np":
            dtype = node.get("dtype")
            if dtype not in _NUMPY_SCALARS:
                raise _Bad(f"a numpy scalar of type {dtype!r}")
            v = self.decode(node.get("v"))
            if not isinstance(v, (bool, int, float)):
                raise _Bad("a malformed numpy scalar")
            return np.dtype(dtype).type(v)
        if t == "ref":
            n = node.get("id")
            if type(n) is not int or n not in self._memo:
                raise _Bad(f"a reference to nothing ({n!r})")
            return self._memo[n]
        if t == "array":
            a = self._key(node)
            self._remember(node, a)
            return a
        if t in ("tuple", "set"):
            items = node.get("items")
            if not isinstance(items, list):
                raise _Bad(f"a {t} without items")
            got = [self.decode(x) for x in items]
            return tuple(got) if t == "tuple" else set(got)
        if t == "dict":
            keys, values = node.get("keys"), node.get("values")
            if not isinstance(keys, list) or not isinstance(values, list):
                raise _Bad("a malformed mapping")
            if len(keys) != len(values):
                raise _Bad("a mapping with more keys than values")
            out: dict[Any, Any] = {}
            for k, x in zip(keys, values, strict=True):
                k = self.decode(k)
                if not isinstance(k, (int, float, str, bool, tuple)) and k is not None:
                    raise _Bad("a mapping keyed by an unhashable value")
                out[k] = self.decode(x)
            return out
        if t in ("floats", "ints"):
            a = self._key(node)
            if a.ndim != 1 or a.dtype != (np.float64 if t == "floats" else np.int64):
                raise _Bad(f"a list of {t} stored as {a.dtype} {a.shape}")
            lst = a.tolist()
            self._remember(node, lst)
            return lst
        if t == "arrays":
            return self._arrays(node)
        if t == "list":
            items = node.get("items")
            if not isinstance(items, list):
                raise _Bad("a list without items")
            lst = []
            self._remember(node, lst)
            lst.extend(self.decode(x) for x in items)
            return lst
        if t == "value":
            return self._value(node)
        if t == "object":
            return self._object(node)
        if t == "method":
            owner = self.decode(node.get("of"))
            name = node.get("name")
            if not isinstance(name, str) or (type(owner).__name__, name) not in _METHODS:
                raise _Bad(f"a method {name!r} that sessions do not hold")
            return getattr(owner, name)
        raise _Bad(f"an unknown entry {t!r}")

    def _arrays(self, node: dict[str, Any]) -> list[NDArray[Any]]:
        data = self._key(node, "data")
        lengths = self._key(node, "lengths")
        index = self._key(node, "index")
        if (
            lengths.dtype != np.int64
            or index.dtype != np.int64
            or lengths.ndim != 1
            or index.ndim != 1
            or data.ndim < 1
            or (lengths < 0).any()
            or int(lengths.sum()) != data.shape[0]
            or (index.size and (index.min() < 0 or index.max() >= lengths.size))
        ):
            raise _Bad("a malformed list of arrays")
        ends = np.cumsum(lengths)
        parts = [
            data[e - n : e].copy() for n, e in zip(lengths.tolist(), ends.tolist(), strict=True)
        ]
        lst = [parts[i] for i in index.tolist()]
        self._remember(node, lst)
        return lst

    def _value(self, node: dict[str, Any]) -> Any:
        name = node.get("class")
        cls = self.values.get(name) if isinstance(name, str) else None
        fields = node.get("fields")
        if cls is None or not isinstance(fields, dict):
            raise _Bad(f"a value of class {name!r}, which sessions do not hold")
        names = {f.name for f in dataclasses.fields(cls) if f.init}
        if set(fields) != names:
            raise _Bad(f"{name} with fields {sorted(fields)}, this probmap has {sorted(names)}")
        values = {k: self.decode(v) for k, v in fields.items()}
        template = _value_template(cls)
        if template is not None:
            for k, v in values.items():
                if not _same_shape(v, getattr(template, k)):
                    raise _Bad(f"{name}.{k} is a {type(v).__name__}")
        try:
            return cls(**values)
        except (TypeError, ValueError) as exc:
            raise _Bad(f"{name}: {exc}") from None

    def _object(self, node: dict[str, Any]) -> Any:
        name = node.get("class")
        cls = self.objects.get(name) if isinstance(name, str) else None
        attrs = node.get("attrs")
        if cls is None or not isinstance(attrs, dict):
            raise _Bad(f"an object of class {name!r}, which sessions do not hold")
        obj: Any = object.__new__(cls)  # no __init__: the attributes are the saved ones
        self._remember(node, obj)
        state = {k: self.decode(v) for k, v in attrs.items() if isinstance(k, str)}
        for k, make in _TRANSIENT.get(str(name), {}).items():
            state[k] = make()
        vars(obj).update(state)
        self.built.append(obj)
        return obj


# ----------------------------------------------------------------------------- checks
def _value_template(cls: type) -> Any:
    """An instance of the value class ``cls`` whose fields have the types a saved one must
    have (the configurations' defaults; None for a class its own checks cover)."""
    from probmap.grid.spec import GridSpec
    from probmap.slam.laser.closures import LoopClosure

    if cls is GridSpec:
        return GridSpec(1.0, (0.0, 0.0), (1, 1))
    if cls is LoopClosure:
        return LoopClosure(0, 0, 0, (0.0, 0.0, 0.0), 0.0, False)
    try:
        return cls()
    except TypeError:  # fields without defaults (MatchField: its own checks)
        return None


def _same_shape(a: Any, b: Any) -> bool:
    """:func:`_same_kind`, and a tuple of the template's length whose items match too."""
    if b is None:
        return True
    if isinstance(b, tuple):
        return (
            isinstance(a, tuple)
            and len(a) == len(b)
            and all(_same_kind(x, y) and x is not None for x, y in zip(a, b, strict=True))
        )
    return a is not None and _same_kind(a, b)


def _templates(slam: SubmapSlam) -> dict[str, Any]:
    """A fresh object of each saved class built with the session's settings: what a loaded
    object's attributes are compared with (names and types)."""
    from probmap.slam.laser.submaps import Submap

    fresh = SubmapSlam(slam.config, max_range=slam.max_range)
    cfg = slam.config
    sm = Submap(0, 0, cfg.submaps.resolution, 0.05, cfg.submaps.field_radius, fresh._model)
    assert sm.grid is not None
    return {
        "SubmapSlam": fresh,
        "LoopClosing": fresh.loops,
        "PoseGraph2D": fresh.graph,
        "Submap": sm,
        "OccupancyGrid": sm.grid,
    }


def _same_kind(a: Any, b: Any) -> bool:
    """Whether a loaded attribute ``a`` has the type of a fresh object's ``b`` (None matches
    anything: optional attributes; numbers match numbers)."""
    if a is None or b is None or type(a) is type(b):
        return True
    num = (int, float, np.integer, np.floating)
    return isinstance(a, num) and isinstance(b, num) and not isinstance(a, bool)


def _check_state(slam: Any, built: list[Any]) -> None:
    """Raise :class:`_Bad` unless the loaded objects have this probmap's attributes, each of
    the type a fresh object has, and the run's per-scan and per-node lists agree."""
    if not isinstance(slam, SubmapSlam):
        raise _Bad("the state is no SubmapSlam")
    for name in ("config", "max_range"):
        if name not in vars(slam):
            raise _Bad(f"the SubmapSlam has no {name}")
    from probmap.slam.laser.submap_slam import SubmapSlamConfig

    if not isinstance(slam.config, SubmapSlamConfig):
        raise _Bad("the configuration is no SubmapSlamConfig")
    if not (isinstance(slam.max_range, float) and slam.max_range > 0):
        raise _Bad("max_range must be a positive number")
    templates = _templates(slam)
    for obj in built:
        name = type(obj).__name__
        fresh = templates[name]
        have, want = set(vars(obj)), set(vars(fresh))
        if have != want:
            diff = sorted(have ^ want)
            raise _Bad(f"{name} with attributes this probmap does not have or lacks: {diff}")
        for k, v in vars(obj).items():
            if not _same_kind(v, getattr(fresh, k)):
                raise _Bad(f"{name}.{k} is a {type(v).__name__}")
    _check_lengths(slam)


def _check_lengths(slam: SubmapSlam) -> None:
    """The per-scan and per-node lists agree in length, every index points inside."""
    s = len(slam.scan_times)
    per_scan: dict[str, list[Any]] = {
        "scan_odometry": slam.scan_odometry, "scan_node": slam.scan_node,
        "scan_offset": slam.scan_offset, "_ranges": slam._ranges, "_angles": slam._angles,
    }  # fmt: skip
    for name, lst in per_scan.items():
        if len(lst) != s:
            raise _Bad(f"{len(lst)} entries in {name} for {s} scans")
    n = slam.nodes
    loops = slam.loops
    per_node: dict[str, list[Any]] = {"node_scan": slam.node_scan, "_travel": slam._travel,
                "closure points": loops._node_points}  # fmt: skip
    for name, lst in per_node.items():
        if len(lst) != n:
            raise _Bad(f"{len(lst)} entries in {name} for {n} nodes")
    if slam.graph.num_nodes != n or slam.graph._poses.shape[0] < n:
        raise _Bad(f"a pose graph of {slam.graph.num_nodes} nodes for {n} nodes")
    for r, a in zip(slam._ranges, slam._angles, strict=True):
        if r.ndim != 1 or r.shape != a.shape:
            raise _Bad("a scan whose ranges and angles differ in shape")
    for name, lst in (("scan_odometry", slam.scan_odometry), ("scan_offset", slam.scan_offset),
                      ("local", slam.local)):  # fmt: skip
        if any(x.shape != (3,) for x in lst):
            raise _Bad(f"an entry of {name} that is not a pose")
    if any(not 0 <= k < max(n, 1) for k in slam.scan_node) or any(
        not 0 <= i < s for i in slam.node_scan
    ):
        raise _Bad("a scan or node index out of range")
    m = slam.graph.num_edges
    g = slam.graph
    if any(x.shape[0] < m for x in (g._ij, g._z, g._info, g._robust)):
        raise _Bad(f"a pose graph of {m} edges with fewer stored")
    if m and (g._ij[:m].min() < 0 or g._ij[:m].max() >= n):
        raise _Bad("a pose-graph edge between nodes that do not exist")
    subs = slam.submaps
    if loops.submaps is not subs or loops.active is not slam.active:
        raise _Bad("the closure search does not share the run's submaps")
    if any(sm.index != i or not 0 <= sm.anchor < max(n, 1) for i, sm in enumerate(subs)):
        raise _Bad("a submap numbered out of order or anchored at no node")


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
    enc = _Encoder()
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
            raise _Bad(f"no array {key!r}")
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
                raise _Bad(f"array {key}: {exc}") from None
            if dtype.hasobject or dtype.kind not in _ARRAY_KINDS or fortran:
                raise _Bad(f"array {key} of dtype {dtype}")
            count = math.prod(shape)
            if f.tell() + count * dtype.itemsize != info.file_size:
                raise _Bad(f"array {key}: its header does not match its size")
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
                raise _Bad("a state larger than the file")
            tree = json.loads(z.read(_STATE).decode("utf-8"))
            dec = _Decoder(_array_reader(p, z))
            slam = dec.decode(tree)
            _check_state(slam, dec.built)
        except _Bad as exc:
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
    two_d = np.ndim(batch.angles) == 2
    return (
        dataclasses.replace(
            batch,
            times=batch.times[k:],
            ranges=batch.ranges[k:],
            angles=batch.angles[k:] if two_d else batch.angles,
            laser_poses=batch.laser_poses[k:],
            robot_poses=batch.robot_poses[k:],
            beams=batch.beams[k:],
        ),
        k,
    )
