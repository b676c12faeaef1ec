"""The state of a :class:`~probmap.slam.laser.submap_slam.SubmapSlam` as plain data, for
:mod:`probmap.pipelines.sessions`: a JSON tree of its objects plus the arrays it names, and
back, without running code from the data.

The tree names each object by one of a fixed list of probmap classes and holds its attributes
(``vars(obj)``, less the caches of :data:`TRANSIENT`); frozen configurations and records are
held by their fields and rebuilt through their own checks; shared objects (the run's submaps,
its pose graph) are references. Lists of one kind are packed into one array. Decoding builds
only the listed classes (``object.__new__`` and their attributes: no ``__init__``, no
``__reduce__``), and :func:`check_state` compares the result with a fresh run of the same
settings (attribute names and types) and checks that its per-scan and per-node lists agree, so
that a crafted or damaged state is a :class:`StateError`, not a failure deep in the run.

A new attribute of one of these classes is saved as it is when its type is one the tree holds
(numbers, strings, None, arrays, lists, tuples, sets, dicts, the listed classes); any other
type is a ``TypeError`` at save time naming the attribute.
"""

from __future__ import annotations

import dataclasses
import math
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from probmap.slam.laser.submap_slam import SubmapSlam

__all__ = ["ARRAY_KINDS", "Decoder", "Encoder", "StateError", "check_state"]


class StateError(Exception):
    """A malformed state (the message says what); the session reader makes it one ValueError
    naming the file."""


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
TRANSIENT: dict[str, dict[str, Callable[[], Any]]] = {
    "LoopClosing": {"_cache": OrderedDict},
    "PoseGraph2D": {"_system": lambda: None, "_system_key": lambda: (-1, -1)},
    "OccupancyGrid": {"_fast": lambda: None},
}
#: Bound methods a saved object may hold: (class of the object bound to, method name).
_METHODS = {("SubmapSlam", "_full_points")}
_NUMPY_SCALARS = ("bool", "int64", "int32", "float64", "float32")
ARRAY_KINDS = "biuf"  # bool, signed and unsigned integers, floats: never objects


class Encoder:
    """Turns a :class:`SubmapSlam` into a JSON tree and a dict of arrays."""

    def __init__(self) -> None:
        self.arrays: dict[str, NDArray[Any]] = {}
        self._memo: dict[int, int] = {}  # id(object) -> reference number
        self._keep: list[Any] = []  # keeps every memoized object alive (ids stay unique)
        self.objects = _object_classes()
        self.values = _value_classes()

    def _array(self, a: NDArray[Any], where: str) -> str:
        if a.dtype.kind not in ARRAY_KINDS:
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
            transient = TRANSIENT.get(name, {})
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


class Decoder:
    """Builds the objects of a JSON tree from :class:`Encoder`, reading arrays on demand."""

    def __init__(self, read_array: Callable[[str], NDArray[Any]]) -> None:
        self._read = read_array
        self._memo: dict[int, Any] = {}
        self.objects = _object_classes()
        self.values = _value_classes()
        self.built: list[Any] = []  # every object built, for the consistency checks

    def _remember(self, node: dict[str, Any], obj: Any) -> None:
        n = node.get("id")
        if type(n) is not int or n in self._memo:
            raise StateError("a malformed reference number")
        self._memo[n] = obj

    def _key(self, node: dict[str, Any], name: str = "key") -> NDArray[Any]:
        key = node.get(name)
        if not isinstance(key, str):
            raise StateError("an array without a name")
        return self._read(key)

    def decode(self, node: Any) -> Any:
        if node is None or isinstance(node, (bool, int, str)):
            return node
        if isinstance(node, float):
            return node
        if not isinstance(node, dict):
            raise StateError(f"an unexpected {type(node).__name__} in the state")
        t = node.get("t")
        if t == "float":
            v = node.get("v")
            if v not in ("nan", "inf", "-inf"):
                raise StateError(f"a malformed number {v!r}")
            return float(v)
        if t == "np":
            dtype = node.get("dtype")
            if dtype not in _NUMPY_SCALARS:
                raise StateError(f"a numpy scalar of type {dtype!r}")
            v = self.decode(node.get("v"))
            if not isinstance(v, (bool, int, float)):
                raise StateError("a malformed numpy scalar")
            return np.dtype(dtype).type(v)
        if t == "ref":
            n = node.get("id")
            if type(n) is not int or n not in self._memo:
                raise StateError(f"a reference to nothing ({n!r})")
            return self._memo[n]
        if t == "array":
            a = self._key(node)
            self._remember(node, a)
            return a
        if t in ("tuple", "set"):
            items = node.get("items")
            if not isinstance(items, list):
                raise StateError(f"a {t} without items")
            got = [self.decode(x) for x in items]
            return tuple(got) if t == "tuple" else set(got)
        if t == "dict":
            keys, values = node.get("keys"), node.get("values")
            if not isinstance(keys, list) or not isinstance(values, list):
                raise StateError("a malformed mapping")
            if len(keys) != len(values):
                raise StateError("a mapping with more keys than values")
            out: dict[Any, Any] = {}
            for k, x in zip(keys, values, strict=True):
                k = self.decode(k)
                if not isinstance(k, (int, float, str, bool, tuple)) and k is not None:
                    raise StateError("a mapping keyed by an unhashable value")
                out[k] = self.decode(x)
            return out
        if t in ("floats", "ints"):
            a = self._key(node)
            if a.ndim != 1 or a.dtype != (np.float64 if t == "floats" else np.int64):
                raise StateError(f"a list of {t} stored as {a.dtype} {a.shape}")
            lst = a.tolist()
            self._remember(node, lst)
            return lst
        if t == "arrays":
            return self._arrays(node)
        if t == "list":
            items = node.get("items")
            if not isinstance(items, list):
                raise StateError("a list without items")
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
                raise StateError(f"a method {name!r} that sessions do not hold")
            return getattr(owner, name)
        raise StateError(f"an unknown entry {t!r}")

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
            raise StateError("a malformed list of arrays")
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
            raise StateError(f"a value of class {name!r}, which sessions do not hold")
        names = {f.name for f in dataclasses.fields(cls) if f.init}
        if set(fields) != names:
            raise StateError(
                f"{name} with fields {sorted(fields)}, this probmap has {sorted(names)}"
            )
        values = {k: self.decode(v) for k, v in fields.items()}
        template = _value_template(cls)
        if template is not None:
            for k, v in values.items():
                if not _same_shape(v, getattr(template, k)):
                    raise StateError(f"{name}.{k} is a {type(v).__name__}")
        try:
            return cls(**values)
        except (TypeError, ValueError) as exc:
            raise StateError(f"{name}: {exc}") from None

    def _object(self, node: dict[str, Any]) -> Any:
        name = node.get("class")
        cls = self.objects.get(name) if isinstance(name, str) else None
        attrs = node.get("attrs")
        if cls is None or not isinstance(attrs, dict):
            raise StateError(f"an object of class {name!r}, which sessions do not hold")
        obj: Any = object.__new__(cls)  # no __init__: the attributes are the saved ones
        self._remember(node, obj)
        state = {k: self.decode(v) for k, v in attrs.items() if isinstance(k, str)}
        for k, make in TRANSIENT.get(str(name), {}).items():
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


def check_state(slam: Any, built: list[Any]) -> None:
    """Raise :class:`StateError` unless the loaded objects have this probmap's attributes, each of
    the type a fresh object has, and the run's per-scan and per-node lists agree."""
    if not isinstance(slam, SubmapSlam):
        raise StateError("the state is no SubmapSlam")
    for name in ("config", "max_range"):
        if name not in vars(slam):
            raise StateError(f"the SubmapSlam has no {name}")
    from probmap.slam.laser.submap_slam import SubmapSlamConfig

    if not isinstance(slam.config, SubmapSlamConfig):
        raise StateError("the configuration is no SubmapSlamConfig")
    if not (isinstance(slam.max_range, float) and slam.max_range > 0):
        raise StateError("max_range must be a positive number")
    templates = _templates(slam)
    for obj in built:
        name = type(obj).__name__
        fresh = templates[name]
        have, want = set(vars(obj)), set(vars(fresh))
        if have != want:
            diff = sorted(have ^ want)
            raise StateError(f"{name} with attributes this probmap does not have or lacks: {diff}")
        for k, v in vars(obj).items():
            if not _same_kind(v, getattr(fresh, k)):
                raise StateError(f"{name}.{k} is a {type(v).__name__}")
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
            raise StateError(f"{len(lst)} entries in {name} for {s} scans")
    n = slam.nodes
    loops = slam.loops
    per_node: dict[str, list[Any]] = {"node_scan": slam.node_scan, "_travel": slam._travel,
                "closure points": loops._node_points}  # fmt: skip
    for name, lst in per_node.items():
        if len(lst) != n:
            raise StateError(f"{len(lst)} entries in {name} for {n} nodes")
    if slam.graph.num_nodes != n or slam.graph._poses.shape[0] < n:
        raise StateError(f"a pose graph of {slam.graph.num_nodes} nodes for {n} nodes")
    for r, a in zip(slam._ranges, slam._angles, strict=True):
        if r.ndim != 1 or r.shape != a.shape:
            raise StateError("a scan whose ranges and angles differ in shape")
    for name, lst in (("scan_odometry", slam.scan_odometry), ("scan_offset", slam.scan_offset),
                      ("local", slam.local)):  # fmt: skip
        if any(x.shape != (3,) for x in lst):
            raise StateError(f"an entry of {name} that is not a pose")
    if any(not 0 <= k < max(n, 1) for k in slam.scan_node) or any(
        not 0 <= i < s for i in slam.node_scan
    ):
        raise StateError("a scan or node index out of range")
    m = slam.graph.num_edges
    g = slam.graph
    if any(x.shape[0] < m for x in (g._ij, g._z, g._info, g._robust)):
        raise StateError(f"a pose graph of {m} edges with fewer stored")
    if m and (g._ij[:m].min() < 0 or g._ij[:m].max() >= n):
        raise StateError("a pose-graph edge between nodes that do not exist")
    subs = slam.submaps
    if loops.submaps is not subs or loops.active is not slam.active:
        raise StateError("the closure search does not share the run's submaps")
    if any(sm.index != i or not 0 <= sm.anchor < max(n, 1) for i, sm in enumerate(subs)):
        raise StateError("a submap numbered out of order or anchored at no node")
